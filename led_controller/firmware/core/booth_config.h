/* Build-time description of one booth: channels, table size, drive resolution.
 * Portable C (no AVR headers); the Makefile may override any of these with -D. */
#ifndef BOOTH_CONFIG_H
#define BOOTH_CONFIG_H

#ifndef BOOTH_FIRMWARE
#define BOOTH_FIRMWARE "msflash-avr-0.1"
#endif
#ifndef BOOTH_CHANNELS
#define BOOTH_CHANNELS 7
#endif
#define BOOTH_STR_(x) #x
#define BOOTH_STR(x) BOOTH_STR_(x)
#define BOOTH_CHANNELS_TEXT BOOTH_STR(BOOTH_CHANNELS)
/* Channel names and peak wavelengths (nm), comma-separated, BOOTH_CHANNELS of each. */
#ifndef BOOTH_NAMES
#define BOOTH_NAMES "led440,led480,led500,led520,led596,led636,led660"
#endif
#ifndef BOOTH_PEAKS
#define BOOTH_PEAKS "440,480,500,520,596,636,660"
#endif
/* Pattern table capacity (STEPS=): BOOTH_CHANNELS * 2 bytes per step of RAM. */
#ifndef BOOTH_MAX_STEPS
#define BOOTH_MAX_STEPS 256
#endif
/* Drive resolution reported as BITS= (12..16); the PWM TOP is (1 << BITS) - 1. */
#ifndef BOOTH_LEVEL_BITS
#define BOOTH_LEVEL_BITS 16
#endif
/* Power-up watchdog period in ms (booth-protocol.md section 7). */
#ifndef BOOTH_WATCHDOG_MS
#define BOOTH_WATCHDOG_MS 3000u
#endif

/* The ExposureActive input's internal pull-up (1: on). Off only for the tests' image that shows
 * what a floating input does. */
#ifndef BOOTH_EXPOSURE_PULLUP
#define BOOTH_EXPOSURE_PULLUP 1
#endif
/* Constant tables and texts kept in flash on an AVR (its RAM is 8 KiB), plain const elsewhere.
 * BOOTH_TEXT("...") is a string literal placed in flash (a static array in the __flash address
 * space, read with LPM through a booth_text_t): on an AVR a plain literal is copied to RAM at
 * start-up, and the replies' texts took 1.2 KiB of it. */
#ifdef __AVR__
#define BOOTH_FLASH __flash
#define BOOTH_TEXT(literal) (__extension__({ static const __flash char booth_text_[] = literal; &booth_text_[0]; }))
#else
#define BOOTH_FLASH
#define BOOTH_TEXT(literal) (literal)
#endif
typedef const BOOTH_FLASH char *booth_text_t;
/* The board's CPU clock: the pulse-dimming arithmetic counts its timer ticks in these cycles. */
#ifndef BOOTH_CLOCK_HZ
#define BOOTH_CLOCK_HZ 16000000ul
#endif
/* Camera master: the most the booth's reaction to ExposureActive may lag the edge (interrupt
 * latency, measured in simavr: docs/flash-energy.md); pulses end this long before the flash
 * window does, so the booth master's pulses tolerate this much camera trigger latency too. */
#ifndef BOOTH_PULSE_MARGIN_US
#define BOOTH_PULSE_MARGIN_US 10u
#endif

#if BOOTH_LEVEL_BITS < 12 || BOOTH_LEVEL_BITS > 16
#error "BOOTH_LEVEL_BITS must be 12..16"
#endif
#if BOOTH_MAX_STEPS < 1 || BOOTH_MAX_STEPS > 65535
#error "BOOTH_MAX_STEPS must be 1..65535"
#endif

#endif

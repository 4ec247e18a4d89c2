/* The booth firmware's portable core: frame parsing, CRC, commands and the sequencer
 * (docs/booth-protocol.md). Plain C99, no AVR headers: the board layer feeds it bytes,
 * trigger-input edges and the time, and implements the board_* hooks below. */
#ifndef BOOTH_CORE_H
#define BOOTH_CORE_H

#include <stdbool.h>
#include <stdint.h>

#include "booth_config.h"

#define BOOTH_MAX_BODY 1024u
#define BOOTH_MAX_LINE (BOOTH_MAX_BODY + 16u) /* a frame with its terminator */
/* Words after the command name kept for parsing: PSET <step> <levels> EXP=<us> NOW is CH + 3; one more
 * word only tells "too many" (the count is capped at BOOTH_MAX_WORDS + 1, never an expected count). */
#define BOOTH_MAX_WORDS (BOOTH_CHANNELS + 4u)
#define BOOTH_OUT_MAX 320u                    /* longest frame the booth sends */
#define BOOTH_SERIAL_MAX 32u                  /* longest serial (SERIAL <text>) */

/* ---- hooks the board layer implements ------------------------------------------------ */

/* Drive the LEDs: one duty value per channel, 0 (off, pin disconnected) .. (1 << BITS) - 1. */
void board_set_levels(const uint16_t duty[BOOTH_CHANNELS]);
/* The camera trigger output (booth-master mode): high or low. */
void board_trigger_out(bool high);
/* Queue bytes for the host (may wait for room; never drops). */
void board_write(const char *data, uint16_t len);
/* Send a frame (up to BOOTH_TIMED_MAX bytes, copied) to the host at at_us: its first byte goes into
 * the UART then, timed by the board's timer (right behind any bytes still queued ahead of it). A
 * frame still waiting from an earlier call goes out at once first (never dropped). A host-paced
 * NEXT's reply, due settle_us after the LED change, goes out this way (from the main loop it was
 * ~57 us late: docs/booth-firmware.md, "Timing"). */
#define BOOTH_TIMED_MAX 40u
void board_write_at(const char *data, uint8_t len, uint32_t at_us);
/* ---- exposure-synchronous pulse dimming (docs/booth-firmware.md, section 2) ---------------
 * A step given its exposure (EXP=) runs in BOOTH and CAMERA mode with each LED on for w*T inside
 * the exposure instead of PWM: every pulse ends `window` timer ticks after the exposure is seen
 * (the trigger output's rising edge, or ExposureActive's), both of its edges on the timer's own
 * compare hardware. */
#define BOOTH_PULSE_FULL 0xFFFFu /* width: on throughout the step */
typedef struct {
    uint8_t clock_select;              /* timer clock: 1..5 = clk/1, /8, /64, /256, /1024 */
    bool on_exposure_input;            /* fire on ExposureActive rising (CAMERA), else with the trigger output */
    uint16_t window;                   /* ticks from the fire to the pulses' common end */
    uint16_t width[BOOTH_CHANNELS];    /* ticks on; 0 off; BOOTH_PULSE_FULL on throughout */
} booth_pulses_t;

/* Drive the LEDs by pulses (armed: they fire once, at the next exposure start), until the next
 * board_set_levels. */
void board_set_pulses(const booth_pulses_t *pulses);
/* The trigger output: high at at_us for width_us, both edges timed by the board's timer (and the
 * armed pulses fired with the rising edge). board_trigger_out(false) cancels it. */
void board_trigger_pulse(uint32_t at_us, uint32_t width_us);
/* Wake the main loop (booth_poll) at at_us. */
void board_wake_at(uint32_t at_us);
/* Microseconds now (wrapping). The core stamps LED changes with it: handling a frame takes
 * the AVR a few hundred us, so the time a frame arrived is too early to settle from. */
uint32_t board_micros(void);
/* The booth's serial, kept in non-volatile memory (EEPROM): load it into out (up to
 * BOOTH_SERIAL_MAX characters and a '\0'; "" when never set), and store a new one. */
void board_serial_load(char out[BOOTH_SERIAL_MAX + 1]);
void board_serial_store(const char *serial, uint8_t len);

/* ---- the core ---------------------------------------------------------------------- */

typedef enum { STATE_IDLE, STATE_ARMED, STATE_RUNNING, STATE_DONE } booth_state_t;
typedef enum { MODE_NONE, MODE_HOST, MODE_BOOTH, MODE_CAMERA } booth_mode_t;
typedef enum { ACTION_NONE, ACTION_APPLY, ACTION_PULSE, ACTION_ADVANCE } booth_action_t;

typedef struct {
    /* the line being received */
    char line[BOOTH_MAX_LINE + 1];
    uint16_t line_len;
    bool discarding;             /* an overlong line: drop bytes up to its '\n' */
    /* LEDs and table (duty values, BITS wide) */
    uint16_t duty[BOOTH_CHANNELS];
    uint16_t table[BOOTH_MAX_STEPS][BOOTH_CHANNELS];
    uint16_t exposure[BOOTH_MAX_STEPS]; /* EXP= of each step, booth_exposure_code(); 0: none (PWM) */
    uint8_t held[(BOOTH_MAX_STEPS + 7) / 8];
    uint16_t steps;
    uint32_t roll_us;            /* ROLL: rolling-shutter skew, first row's start to the last's */
    /* sequencer */
    booth_state_t state;
    booth_mode_t mode;
    uint32_t settle_us, pulse_us, period_us;
    int32_t step;
    bool holding;
    uint32_t triggers;
    uint32_t t0_us;              /* start of step 0's slot (BOOTH), wrapping */
    booth_action_t action;
    uint32_t action_due_us;
    bool pulse_high;
    uint32_t pulse_end_us;
    /* a reply sent once the LEDs have settled (NEXT): framed at once, the board sends it at due */
    uint32_t deferred_due_us;
    /* link bookkeeping */
    uint8_t event_seq;
    uint32_t watchdog_ms;
    uint32_t last_host_us;
    bool watchdog_tripped;
    booth_text_t last_error;     /* the code of the last refusal (in flash); NULL: none */
    uint16_t bad_frames;
    /* the serial, as loaded from EEPROM at boot ("" when never set) */
    char serial[BOOTH_SERIAL_MAX + 1];
} booth_t;

/* An exposure in us as 16 bits: below 4096 exact, above m << e with a 12-bit m (0.025 %). */
uint16_t booth_exposure_code(uint32_t exposure_us);
uint32_t booth_exposure_us(uint16_t code);
/* The pulses of a step of these levels and exposure code (false: PWM); camera: CAMERA mode. */
bool booth_pulse_plan(const booth_t *b, const uint16_t duty[BOOTH_CHANNELS], uint16_t code, bool camera,
                      booth_pulses_t *plan);

/* CRC-16/CCITT-FALSE over len bytes (poly 0x1021, init 0xFFFF). */
uint16_t booth_crc16(const uint8_t *data, uint16_t len);

/* Power-up state, the serial loaded (board_serial_load), and the boot banner: a line end and the
 * BOOT event (docs/booth-protocol.md section 6). */
void booth_init(booth_t *b, uint32_t now_us);
/* One byte from the host; a complete line is answered at once (through board_write). */
void booth_feed(booth_t *b, uint8_t byte, uint32_t now_us);
/* An edge of the camera's ExposureActive line (true: rising, exposure starts). */
void booth_exposure(booth_t *b, bool active, uint32_t now_us);
/* Run what is due: booth-master steps and pulses, the camera's rolling-shutter advance, the watchdog. */
void booth_poll(booth_t *b, uint32_t now_us);
/* All LEDs off and any sequence aborted (the host link is gone, a fault). */
void booth_all_off(booth_t *b);

#endif

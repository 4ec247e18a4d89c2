/* pin_model: the LED pins of the booth firmware (OC3A..OC5C) computed from the firmware's own
 * register writes, per the ATmega2560 datasheet (section 17, "16-bit Timer/Counter (Timer/Counter
 * 1, 3, 4, and 5)"), in place of simavr 1.6's timers 3, 4 and 5.
 *
 * simavr 1.6 gets these pins wrong for the booth firmware (an OCR write whose low byte is
 * unchanged is ignored, OCR = TOP gives a constant low instead of high, OCR changes act at once
 * instead of at BOTTOM, TCNT writes above TOP are dropped) and steps a 16-bit timer whose TOP is
 * ICRn nearly cycle by cycle. pin_model_install() takes the register writes of timers 3, 4, 5
 * away from simavr (its timers stay stopped, so the simulation runs at real time) and models:
 * the waveform generation modes 0 (normal), 4 and 12 (CTC), 14 and 15 (fast PWM); the clock
 * selects 1, 8, 64, 256, 1024 on the shared prescaler (ticks at cycle multiples of the
 * division); the TEMP register of 16-bit writes; OCR double buffering (loaded at BOTTOM in fast
 * PWM, at once otherwise); TCNT writes, which block the compare match of the next timer clock;
 * the COM bits (toggle, clear, set; the pin is the port bit while disconnected) and force
 * output compare (non-PWM modes only). A compare match acts on the timer clock after TCNT
 * equalled OCR, BOTTOM after the compare on the same clock. Every pin edge is logged with its
 * cycle, so the on-time of an LED pin over any past window is exact (pin_model_on_cycles).
 * The firmware must not read TCNT3..5 or use their interrupts: neither is modelled (a write to
 * TIMSK3..5 is reported on stderr). */
#ifndef PIN_MODEL_H
#define PIN_MODEL_H

#include <stdint.h>

#include "sim_avr.h"

#define PM_CHANNELS 9 /* OC3A OC3B OC3C OC4A OC4B OC4C OC5A OC5B OC5C, in this order */

void pin_model_install(avr_t *avr);
/* After a reset of the core (avr_reset, the watchdog): registers cleared, pins inputs. */
void pin_model_reset(void);
/* Process every timer clock up to the current cycle (call after each simulation step). */
void pin_model_advance(void);
/* Pin level now (0/1). */
int pin_model_pin(int channel);
/* What the channel is driven with, as a level in [0, 1]: a fast-PWM duty (high ticks per period
 * / (TOP + 1)), the port bit of a disconnected pin (0 or 1), or the pin level now when the timer
 * does not run periodically (stopped, or a one-shot TOP of 0). */
double pin_model_level(int channel);
/* Cycle of the last write that configures the LED pins: any register of timers 3..5 but TCNT
 * (whose writes start pulses), or their port and DDR registers (the LEDs' settle starts there). */
avr_cycle_count_t pin_model_changed_at(void);
/* Cycles the pin was high in [from, to): -1 if the window is not wholly in the past or older
 * than the edge log. */
int64_t pin_model_on_cycles(int channel, avr_cycle_count_t from, avr_cycle_count_t to);
/* Trace hook: called with (timer 3..5, cycle) on every TCNT write (NULL: none). */
extern void (*pin_model_tcnt_hook)(int timer, avr_cycle_count_t cycle);

#endif

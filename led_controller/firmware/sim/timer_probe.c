/* timer_probe: a small AVR image of known pin waveforms, to prove sim/pin_model.c (the LED pins
 * booth_sim computes from register writes) against the datasheet's arithmetic. Built by `make sim`
 * as build/timer_probe.elf; tests/led_controller/test_pin_model.py reads its pins through the
 * harness. Each marker is a pulse on PA0 (the harness prints "pulse <t_us> ...").
 *
 * - Timer3, fast PWM mode 14, TOP = ICR3 = 0xFFFF, clk/1 (the booth's PWM):
 *   OC3A non-inverting, OCR3A = 0x3FFF: high 0x4000 of 0x10000 ticks (0.25);
 *   OC3B non-inverting, OCR3B = TOP: constantly high (simavr 1.6: constantly low);
 *   OC3C inverting, OCR3C = 0xBFFF: high TOP - OCR = 0x4000 ticks (0.25).
 * - Timer5, mode 14, TOP = ICR5 = 0x0FFF, clk/1: OC5A non-inverting, OCR5A = 0x0400 (0x401 of
 *   0x1000 ticks); after marker 3 OCR5A = 0x0800, whose low byte is unchanged (simavr 1.6 ignores
 *   such a write): 0x801 of 0x1000 ticks from the next BOTTOM on.
 * - Timer4, mode 14 with TOP = ICR4 = 0 (the counter rests at 0), clk/8, COM = 3 (set on
 *   compare, clear at BOTTOM): a write TCNT4 = 0x10000 - 1500 runs it once to 0xFFFF and back to 0,
 *   a one-shot: OC4A (OCR4A = 65535 - 1000) high 1000 ticks = 500 us, OC4B (OCR4B = 65534) one
 *   tick = 0.5 us; both end on the clock that wraps to 0, 1500 ticks after the write. OC4C
 *   (OCR4C = 65535 - 1499, the value written to TCNT4): a TCNT write blocks the compare match of
 *   the next timer clock, so OC4C never goes high. Fired once after every marker.
 */
#include <avr/io.h>
#include <util/delay.h>

static void marker(void)
{
    PORTA |= _BV(PA0);
    _delay_us(20);
    PORTA &= (uint8_t)~_BV(PA0);
}

int main(void)
{
    DDRA |= _BV(PA0);
    DDRE |= _BV(PE3) | _BV(PE4) | _BV(PE5);
    DDRH |= _BV(PH3) | _BV(PH4) | _BV(PH5);
    DDRL |= _BV(PL3);

    ICR3 = 0xFFFF;
    OCR3A = 0x3FFF;
    OCR3B = 0xFFFF;
    OCR3C = 0xBFFF;
    TCCR3A = _BV(COM3A1) | _BV(COM3B1) | _BV(COM3C1) | _BV(COM3C0) | _BV(WGM31);
    TCCR3B = _BV(WGM33) | _BV(WGM32) | _BV(CS30);

    ICR5 = 0x0FFF;
    OCR5A = 0x0400;
    TCCR5A = _BV(COM5A1) | _BV(WGM51);
    TCCR5B = _BV(WGM53) | _BV(WGM52) | _BV(CS50);

    ICR4 = 0;
    TCNT4 = 0;
    OCR4A = 65535u - 1000u;
    OCR4B = 65534u;
    OCR4C = 65535u - 1499u;
    TCCR4B = _BV(WGM43) | _BV(WGM42) | _BV(CS41);
    TCCR4A = _BV(COM4A1) | _BV(COM4A0) | _BV(COM4B1) | _BV(COM4B0) | _BV(COM4C1) | _BV(COM4C0) | _BV(WGM41);

    for (uint8_t n = 0;; n++) {
        _delay_ms(5);
        marker();
        TCNT4 = (uint16_t)(0x10000ul - 1500u);
        if (n == 3)
            OCR5A = 0x0800;
    }
}

/* Board layer for an ATmega2560 at 16 MHz (Arduino Mega 2560 class): UART0, the time base,
 * the LED PWM, the trigger pins and the hardware watchdog; everything else is the portable
 * core (core/booth_core.c). Pins: docs/booth-firmware.md. */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "booth_core.h"
#include "pins_mega2560.h"

/* The trigger and ExposureActive pins, from the pin table. */
#define TRIG_PORT_(port, bit, arduino) PORT##port
#define TRIG_DDR_(port, bit, arduino) DDR##port
#define TRIG_BIT_(port, bit, arduino) P##port##bit
#define EXP_PIN_(port, bit, arduino, irq) PIN##port
#define EXP_PORT_(port, bit, arduino, irq) PORT##port
#define EXP_DDR_(port, bit, arduino, irq) DDR##port
#define EXP_BIT_(port, bit, arduino, irq) P##port##bit
#define TRIGGER_PORT BOOTH_TRIGGER_OUT(TRIG_PORT_)
#define TRIGGER_DDR BOOTH_TRIGGER_OUT(TRIG_DDR_)
#define TRIGGER_BIT BOOTH_TRIGGER_OUT(TRIG_BIT_)
#define EXPOSURE_PIN BOOTH_EXPOSURE_IN(EXP_PIN_)
#define EXPOSURE_PORT BOOTH_EXPOSURE_IN(EXP_PORT_)
#define EXPOSURE_DDR BOOTH_EXPOSURE_IN(EXP_DDR_)
#define EXPOSURE_BIT BOOTH_EXPOSURE_IN(EXP_BIT_)

#if F_CPU != 16000000UL
#error "board_mega2560.c: timer and baud settings assume F_CPU 16 MHz"
#endif

#define LEVEL_TOP ((uint16_t)((1ul << BOOTH_LEVEL_BITS) - 1u))
#define TICK_US 250u /* Timer1 compare period: wakes the main loop for timed actions */

/* ---- UART0: 115200 8N1, interrupt-driven rings ----------------------------------------- */

#define RX_SIZE 256u /* a power of two */
#define TX_SIZE 256u

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint16_t rx_head, rx_tail;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint16_t tx_head, tx_tail;

ISR(USART0_RX_vect)
{
    uint8_t byte = UDR0;
    uint16_t next = (rx_head + 1u) & (RX_SIZE - 1u);
    if (next != rx_tail) { /* a full ring drops the byte: the frame then fails its CRC/length check */
        rx_buf[rx_head] = byte;
        rx_head = next;
    }
}

ISR(USART0_UDRE_vect)
{
    if (tx_tail == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (tx_tail + 1u) & (TX_SIZE - 1u);
}

static bool rx_pop(uint8_t *byte)
{
    bool got = false;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        if (rx_tail != rx_head) {
            *byte = rx_buf[rx_tail];
            rx_tail = (rx_tail + 1u) & (RX_SIZE - 1u);
            got = true;
        }
    }
    return got;
}

void board_write(const char *data, uint16_t len)
{
    while (len--) {
        uint16_t next = (tx_head + 1u) & (TX_SIZE - 1u);
        while (next == tx_tail) /* full: the UDRE interrupt makes room */
            wdt_reset();
        tx_buf[tx_head] = (uint8_t)*data++;
        ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
        {
            tx_head = next;
            UCSR0B |= _BV(UDRIE0);
        }
    }
}

static void uart_init(void)
{
    UCSR0A = _BV(U2X0);
    UBRR0 = 16; /* 16 MHz / (8 * 17) = 117647 baud, 2.1 % from 115200, as the Arduino core */
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
}

/* ---- time base: Timer1 CTC every 250 us, 0.5 us resolution ------------------------------ */

#define TICK_COUNTS (2u * TICK_US) /* TCNT1 counts per tick (2 MHz) */
static volatile uint32_t tick_us; /* board_micros() at the start of the current tick */

/* Timed events on Timer1's compare B (docs/booth-firmware.md, "Timing"): the trigger pulse's
 * edges and a timed frame's first byte, timed to the timer's count rather than to the main loop's
 * next wake-up (which the 250 us tick made 250 us late at worst), and wake-ups of the main loop for
 * due actions. */
#define EVENT_RISE 0
#define EVENT_FALL 1
#define EVENT_WAKE 2
#define EVENT_SEND 3 /* a timed frame's first byte into the UART (board_write_at) */
#define EVENTS 4
static volatile uint8_t event_pending;      /* bit per event */
static volatile uint32_t event_at[EVENTS];  /* board_micros() time of each */
static void fire_on_trigger(void);

/* The start of the tick TCNT1 read `count` in (interrupts off): a wrap whose interrupt has not run
 * yet shows as compare A's flag with a small count. */
static uint32_t tick_start_locked(uint16_t count)
{
    uint32_t start = tick_us;
    if ((TIFR1 & _BV(OCF1A)) && count < TICK_COUNTS / 2u)
        start += TICK_US;
    return start;
}

static uint32_t micros_locked(void) /* with interrupts off */
{
    uint16_t count = TCNT1;
    return tick_start_locked(count) + count / 2u;
}

uint32_t board_micros(void)
{
    uint32_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { t = micros_locked(); }
    return t;
}

static volatile uint8_t woken; /* a wake-up ran: the main loop polls before it sleeps again */

/* The frame of board_write_at, waiting for its time. */
static char timed_frame[BOOTH_TIMED_MAX];
static volatile uint8_t timed_len;   /* 0: none */
static volatile uint8_t timed_late;  /* due, but the ring had no room: the main loop queues it */

/* Queue the timed frame now (interrupts off): its first byte straight into the UART when nothing is
 * ahead of it, the rest into the ring for the UDRE interrupt. */
static void send_timed(void)
{
    uint8_t len = timed_len, i = 0;
    uint16_t head = tx_head;
    if (len > ((tx_tail - head - 1u) & (TX_SIZE - 1u))) {
        timed_late = 1; /* no room: behind the bytes queued ahead, from the main loop */
        woken = 1;
        return;
    }
    if (tx_tail == head && (UCSR0A & _BV(UDRE0)))
        UDR0 = (uint8_t)timed_frame[i++];
    for (; i < len; i++) {
        tx_buf[head] = (uint8_t)timed_frame[i];
        head = (head + 1u) & (TX_SIZE - 1u);
    }
    tx_head = head;
    timed_len = 0;
    UCSR0B |= _BV(UDRIE0);
}

static void run_event(uint8_t e)
{
    if (e == EVENT_RISE) {
        TRIGGER_PORT |= _BV(TRIGGER_BIT);
        fire_on_trigger(); /* the LED pulses start with the trigger edge, a few cycles later */
    } else if (e == EVENT_FALL) {
        TRIGGER_PORT &= (uint8_t)~_BV(TRIGGER_BIT);
    } else if (e == EVENT_SEND) {
        send_timed();
    } else {
        woken = 1;
    }
    event_pending &= (uint8_t)~_BV(e);
}

/* Counts (24 us) compare B fires ahead of a timed event (a trigger edge, a timed frame), which then
 * waits for its exact count: more than the interrupt's entry and arm_events' look through the
 * pending events take (measured in simavr: ~21 us before that look was made cheaper, when events
 * ran up to 20 us late with a 10 us lead). */
#define LEAD 48

/* TCNT1 now, counted from the start of the tick in which TCNT1 read `since` (one wrap at most). */
static uint16_t count_since(uint16_t since)
{
    uint16_t count = TCNT1;
    return count < since ? (uint16_t)(count + TICK_COUNTS) : count;
}

/* Wait until TCNT1 reaches `target`, counted from the start of the tick in which TCNT1 read `since`
 * (target may lie up to LEAD counts into the next tick). A wrap since then is seen whenever it
 * happened: a wait whose first reading came after the wrap waited a whole tick (250 us late), and
 * one whose target lay in the next tick ended at the wrap (early). */
static void wait_count(uint16_t target, uint16_t since)
{
    uint16_t last = since;
    for (;;) {
        uint16_t count = TCNT1;
        if (count < last && target >= TICK_COUNTS)
            target = (uint16_t)(target - TICK_COUNTS); /* the tick wrapped: the target is in this one */
        else if (count < last)
            return; /* wrapped past a target of the earlier tick */
        if (count >= target)
            return;
        last = count;
    }
}

/* Run what is due and set compare B for the next event (interrupts off). Compare B sets its flag
 * as TCNT1 leaves OCR1B; for the trigger's edges and a timed frame it is set LEAD counts early and
 * the interrupt waits for the exact count (0.5 us), so an edge does not depend on how long the
 * interrupt takes to get there: a pulse's width and its settle are exact to a count, whatever else
 * is pending. The decision uses TCNT1 read after the look through the events (a count read before
 * it was up to 15 us stale). Wake-ups run at their count plus the entry time. A stale compare flag
 * (an earlier match) only brings the interrupt early, which finds nothing due and sets OCR1B
 * again: the flag is never cleared by writing TIFR1 (simavr 1.6 clears every Timer1 flag on such a
 * write, compare A's tick too). */
static void arm_events(void)
{
    for (;;) {
        uint16_t since = TCNT1;
        uint32_t start = tick_start_locked(since);
        int8_t next = -1;
        int32_t ahead_us = 0; /* from this tick's start */
        for (uint8_t e = 0; e < EVENTS; e++) {
            if (!(event_pending & _BV(e)))
                continue;
            int32_t at = (int32_t)(event_at[e] - start);
            if (next < 0 || at < ahead_us) {
                next = (int8_t)e;
                ahead_us = at;
            }
        }
        if (next < 0) {
            TIMSK1 &= (uint8_t)~_BV(OCIE1B);
            return;
        }
        /* A wake-up never runs early (the loop would find nothing due and sleep a tick); an edge
         * or a frame due within LEAD waits here for its count. */
        uint16_t lead = next == EVENT_WAKE ? 0 : LEAD;
        uint16_t now = count_since(since);
        if (ahead_us <= (int32_t)(now + lead) / 2) { /* due: now (an edge at its count) */
            if (lead && ahead_us > 0)
                wait_count((uint16_t)(2 * ahead_us), since);
            run_event((uint8_t)next);
            continue;
        }
        uint16_t target = (uint16_t)(ahead_us > (int32_t)TICK_US * 3 ? 3 * TICK_COUNTS : 2 * ahead_us);
        uint16_t at = (uint16_t)(target - 1u - (lead ? lead - 2u : 0u));
        if (at >= TICK_COUNTS) { /* in a later tick: the tick interrupt arms it then */
            TIMSK1 &= (uint8_t)~_BV(OCIE1B);
            return;
        }
        OCR1B = at;
        TIMSK1 |= _BV(OCIE1B);
        if (count_since(since) < at) /* else this loop took so long that the count passed: run it from here */
            return;
    }
}

ISR(TIMER1_COMPA_vect)
{
    tick_us += TICK_US;
    if (event_pending)
        arm_events();
}

ISR(TIMER1_COMPB_vect) { arm_events(); }

static void schedule_event(uint8_t e, uint32_t at_us)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        event_at[e] = at_us;
        event_pending |= _BV(e);
        arm_events();
    }
}

void board_trigger_pulse(uint32_t at_us, uint32_t width_us)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        event_at[EVENT_FALL] = at_us + width_us;
        event_pending |= _BV(EVENT_FALL);
        schedule_event(EVENT_RISE, at_us);
    }
}

void board_wake_at(uint32_t at_us) { schedule_event(EVENT_WAKE, at_us); }

void board_write_at(const char *data, uint8_t len, uint32_t at_us)
{
    uint8_t waiting;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        waiting = timed_len;
        event_pending &= (uint8_t)~_BV(EVENT_SEND);
        timed_len = 0;
        timed_late = 0;
    }
    if (waiting) /* an earlier frame not yet sent: at once, before this one */
        board_write(timed_frame, waiting);
    if (len > BOOTH_TIMED_MAX)
        len = BOOTH_TIMED_MAX;
    for (uint8_t i = 0; i < len; i++)
        timed_frame[i] = data[i];
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        timed_len = len;
        schedule_event(EVENT_SEND, at_us);
    }
}

static void timebase_init(void)
{
    TCCR1A = 0;
    OCR1A = TICK_US * 2u - 1u;               /* 500 counts at 2 MHz */
    TCCR1B = _BV(WGM12) | _BV(CS11);         /* CTC on OCR1A, clk/8 */
    TIMSK1 = _BV(OCIE1A);
}

/* ---- LED drive: timers 3, 4, 5 -------------------------------------------------------------
 * PWM (board_set_levels): fast PWM mode 14, TOP = ICRn = 2^BITS - 1, clk/1, non-inverting: high
 * OCR + 1 of TOP + 1 ticks (OCR = TOP: constantly high), OCR chosen by pwm_ocr.
 * Pulses (board_set_pulses): mode 14 with TOP = ICRn = 0, so the counter rests at 0; inverting
 * output (set on compare match, clear at BOTTOM). Writing TCNTn = 0x10000 - window runs the counter
 * once up to 0xFFFF and back to 0: a channel with OCR = 0xFFFF - width is high for exactly `width`
 * ticks, ending `window` ticks after the write, both edges on the timer's compare hardware
 * (ATmega2560 datasheet, section 17.9.3 and the note on TOP below TCNT in 17.9.3). */

typedef struct {
    volatile uint8_t *tccra;
    volatile uint16_t *ocr;
    uint8_t com1, com0;      /* COMnx1, COMnx0 */
    uint8_t foc;             /* FOCnx in TCCRnC */
    volatile uint8_t *port, *ddr;
    uint8_t bit;
} pwm_channel_t;

/* Channel order = NAMES= order; the pins are board/pins_mega2560.h's (Arduino D5, D2, D3, D6, D7, D8, D46). */
#define PWM_CHANNEL(index, port, bit, arduino, timer, unit)                                              \
    {&TCCR##timer##A, &OCR##timer##unit, COM##timer##unit##1, COM##timer##unit##0, FOC##timer##unit, &PORT##port, \
     &DDR##port, P##port##bit},
static const __flash pwm_channel_t channels[] = {BOOTH_LED_PINS(PWM_CHANNEL)};
#undef PWM_CHANNEL
_Static_assert(sizeof channels / sizeof channels[0] >= BOOTH_CHANNELS, "more channels than PWM outputs");

typedef struct {
    volatile uint8_t *tccra, *tccrb, *tccrc;
    volatile uint16_t *icr, *tcnt;
} led_timer_t;

static const __flash led_timer_t led_timers[3] = {
    {&TCCR3A, &TCCR3B, &TCCR3C, &ICR3, &TCNT3},
    {&TCCR4A, &TCCR4B, &TCCR4C, &ICR4, &TCNT4},
    {&TCCR5A, &TCCR5B, &TCCR5C, &ICR5, &TCNT5},
};
#define WGM_14_A _BV(WGM31)                 /* WGMn1 in TCCRnA (same bit for timers 3, 4, 5) */
#define WGM_14_B (_BV(WGM33) | _BV(WGM32))  /* WGMn3:2 in TCCRnB */

/* Armed pulses: the TCNT value that starts them, and what fires them. */
static volatile uint16_t fire_start;
static volatile uint8_t fire_with_trigger, fire_with_exposure;

static inline void fire(void)
{
    uint16_t start = fire_start;
    TCNT3 = start;
    TCNT4 = start;
    TCNT5 = start;
}

static void fire_on_trigger(void) /* interrupts off */
{
    if (fire_with_trigger) {
        fire();
        fire_with_trigger = 0;
    }
}

static void disarm(void)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { fire_with_trigger = fire_with_exposure = 0; }
}

/* The compare value whose duty (OCR + 1) / (TOP + 1) is nearest the level duty / TOP. */
static uint16_t pwm_ocr(uint16_t duty) { return (uint16_t)(duty - 1u + (duty > LEVEL_TOP / 2u)); }

void board_set_levels(const uint16_t duty[BOOTH_CHANNELS])
{
    disarm();
    for (uint8_t t = 0; t < 3; t++) { /* PWM at clk/1, TOP = 2^BITS - 1 (a no-op when already so) */
        *led_timers[t].icr = LEVEL_TOP;
        *led_timers[t].tccrb = WGM_14_B | _BV(CS30);
        *led_timers[t].tccra = (uint8_t)((*led_timers[t].tccra & ~3u) | WGM_14_A);
    }
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        const __flash pwm_channel_t *ch = &channels[c];
        if (duty[c] == 0) {
            /* Off is off: disconnect the compare output (fast PWM at OCR 0 still spikes). */
            *ch->tccra &= (uint8_t)~(_BV(ch->com1) | _BV(ch->com0));
            *ch->port &= (uint8_t)~_BV(ch->bit);
            *ch->ocr = 0;
        } else {
            *ch->ocr = duty[c] >= LEVEL_TOP ? LEVEL_TOP : pwm_ocr(duty[c]);
            *ch->tccra = (uint8_t)((*ch->tccra & ~_BV(ch->com0)) | _BV(ch->com1));
        }
    }
    /* In fast PWM the OCR registers are double-buffered and load at BOTTOM: up to one PWM
     * period (4.1 ms at 16 bits) late, longer than a short settle. Setting the counters to
     * TOP makes the next clock load the new duties at once (the running period is cut short):
     * every period then starts a whole number of periods after this write. */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        TCNT3 = LEVEL_TOP;
        TCNT4 = LEVEL_TOP;
        TCNT5 = LEVEL_TOP;
    }
}

void board_set_pulses(const booth_pulses_t *p)
{
    disarm();
    /* Every pin on its port bit first: off, or on throughout the step. */
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        const __flash pwm_channel_t *ch = &channels[c];
        *ch->tccra &= (uint8_t)~(_BV(ch->com1) | _BV(ch->com0));
        if (p->width[c] == BOOTH_PULSE_FULL)
            *ch->port |= _BV(ch->bit);
        else
            *ch->port &= (uint8_t)~_BV(ch->bit);
    }
    /* Timers stopped in normal mode: clear the compare latches the pulses will use (force output
     * compare, 'clear' action; the pin an input meanwhile, so a latch left high by PWM never shows),
     * set the OCRs (not buffered in normal mode), then mode 14 with TOP 0 and the clock. */
    for (uint8_t t = 0; t < 3; t++) {
        *led_timers[t].tccrb = 0;
        *led_timers[t].tccra = 0;
        *led_timers[t].icr = 0;
        *led_timers[t].tcnt = 0;
    }
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        const __flash pwm_channel_t *ch = &channels[c];
        uint8_t t = c / 3u;
        if (p->width[c] == 0 || p->width[c] == BOOTH_PULSE_FULL)
            continue;
        *ch->ddr &= (uint8_t)~_BV(ch->bit);
        *ch->tccra |= _BV(ch->com1);                       /* 'clear on compare' */
        *led_timers[t].tccrc = _BV(ch->foc);               /* forced: latch low */
        *ch->tccra |= _BV(ch->com0);                       /* 'set on compare, clear at BOTTOM' */
        *ch->ddr |= _BV(ch->bit);
        *ch->ocr = (uint16_t)(0xFFFFu - p->width[c]);
    }
    for (uint8_t t = 0; t < 3; t++) {
        *led_timers[t].tccra |= WGM_14_A;
        *led_timers[t].tccrb = WGM_14_B | p->clock_select;
    }
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        fire_start = (uint16_t)(0x10000ul - p->window);
        if (p->on_exposure_input)
            fire_with_exposure = 1;
        else
            fire_with_trigger = 1;
    }
}

static void pwm_init(void)
{
    PORTE &= (uint8_t)~(_BV(PE3) | _BV(PE4) | _BV(PE5));
    PORTH &= (uint8_t)~(_BV(PH3) | _BV(PH4) | _BV(PH5));
    PORTL &= (uint8_t)~_BV(PL3);
    DDRE |= _BV(PE3) | _BV(PE4) | _BV(PE5);
    DDRH |= _BV(PH3) | _BV(PH4) | _BV(PH5);
    DDRL |= _BV(PL3);
    ICR3 = LEVEL_TOP;
    ICR4 = LEVEL_TOP;
    ICR5 = LEVEL_TOP;
    TCCR3A = _BV(WGM31);
    TCCR4A = _BV(WGM41);
    TCCR5A = _BV(WGM51);
    TCCR3B = _BV(WGM33) | _BV(WGM32) | _BV(CS30);
    TCCR4B = _BV(WGM43) | _BV(WGM42) | _BV(CS40);
    TCCR5B = _BV(WGM53) | _BV(WGM52) | _BV(CS50);
}

/* ---- trigger pins: ExposureActive in on INT0 (PD0, D21), trigger out on PA0 (D22) -------- */

/* From board/pins_mega2560.h. The ExposureActive input must be INT0's pin (its vector is below). */

#define EDGE_SIZE 16u
static volatile uint8_t edge_buf[EDGE_SIZE];
static volatile uint8_t edge_head, edge_tail;

ISR(INT0_vect)
{
    uint8_t level = (uint8_t)(EXPOSURE_PIN & _BV(EXPOSURE_BIT));
    if (level && fire_with_exposure) { /* camera master: the LED pulses start with the exposure */
        fire();
        fire_with_exposure = 0;
    }
    uint8_t next = (uint8_t)((edge_head + 1u) & (EDGE_SIZE - 1u));
    if (next != edge_tail) {
        edge_buf[edge_head] = level;
        edge_head = next;
    }
}

static bool edge_pop(bool *high)
{
    bool got = false;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        if (edge_tail != edge_head) {
            *high = edge_buf[edge_tail] != 0;
            edge_tail = (uint8_t)((edge_tail + 1u) & (EDGE_SIZE - 1u));
            got = true;
        }
    }
    return got;
}

void board_trigger_out(bool high)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        event_pending &= (uint8_t)~(_BV(EVENT_RISE) | _BV(EVENT_FALL)); /* a scheduled pulse too */
        if (high)
            TRIGGER_PORT |= _BV(TRIGGER_BIT);
        else
            TRIGGER_PORT &= (uint8_t)~_BV(TRIGGER_BIT);
    }
}

static void trigger_init(void)
{
    TRIGGER_PORT &= (uint8_t)~_BV(TRIGGER_BIT);
    TRIGGER_DDR |= _BV(TRIGGER_BIT);
    EXPOSURE_DDR &= (uint8_t)~_BV(EXPOSURE_BIT);
#if BOOTH_EXPOSURE_PULLUP
    EXPOSURE_PORT |= _BV(EXPOSURE_BIT); /* internal pull-up: a loose wire reads high (no exposure edges), never floats */
#endif
    EICRA = (EICRA & (uint8_t)~(_BV(ISC01) | _BV(ISC00))) | _BV(ISC00); /* any edge */
    EIFR = _BV(INTF0);
    EIMSK |= _BV(INT0);
}

/* ---- the serial in EEPROM: 'M' 'S' <length> <text>, from address 0 ----------------------- */

#define SERIAL_EEPROM ((uint8_t *)0)
static const __flash uint8_t serial_magic[2] = {'M', 'S'};

void board_serial_load(char out[BOOTH_SERIAL_MAX + 1])
{
    uint8_t head[3];
    eeprom_read_block(head, SERIAL_EEPROM, sizeof head);
    out[0] = '\0';
    if (head[0] != serial_magic[0] || head[1] != serial_magic[1] || head[2] == 0 || head[2] > BOOTH_SERIAL_MAX)
        return; /* blank (0xFF) or foreign EEPROM: no serial */
    eeprom_read_block(out, SERIAL_EEPROM + 3, head[2]);
    out[head[2]] = '\0';
}

void board_serial_store(const char *serial, uint8_t len)
{
    /* eeprom_update_* writes only the bytes that change (3.4 ms each; SERIAL is refused while a
     * sequence runs, and the hardware watchdog's 500 ms covers 35 bytes). */
    uint8_t head[3] = {serial_magic[0], serial_magic[1], len};
    eeprom_update_block(serial, SERIAL_EEPROM + 3, len);
    eeprom_update_block(head, SERIAL_EEPROM, sizeof head);
}

/* ---- main ----------------------------------------------------------------------------- */

/* A watchdog reset leaves the WDT running: stop it before anything else (and read why). */
uint8_t reset_cause __attribute__((section(".noinit")));
void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
    reset_cause = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

static booth_t booth;

int main(void)
{
    pwm_init(); /* LEDs off before anything else */
    trigger_init();
    uart_init();
    timebase_init();
    sei();
    booth_init(&booth, board_micros());
    /* The hardware watchdog resets a hung firmware (pins go to inputs: LEDs off). */
    wdt_enable(WDTO_500MS);
    set_sleep_mode(SLEEP_MODE_IDLE);
    for (;;) {
        uint8_t byte;
        bool high;
        wdt_reset();
        while (rx_pop(&byte))
            booth_feed(&booth, byte, board_micros());
        while (edge_pop(&high))
            booth_exposure(&booth, high, board_micros());
        if (timed_late) { /* a timed frame found the ring full: behind what is queued */
            uint8_t len;
            ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
            {
                len = timed_len;
                timed_len = timed_late = 0;
            }
            board_write(timed_frame, len);
        }
        booth_poll(&booth, board_micros());
        cli();
        if (woken) { /* a wake-up ran while this loop was busy: poll again before sleeping */
            woken = 0;
            sei();
        } else if (rx_tail == rx_head && edge_tail == edge_head) {
            sleep_enable();
            sei(); /* the instruction after sei runs before any interrupt: no lost wake-up */
            sleep_cpu();
            sleep_disable();
        } else {
            sei();
        }
    }
}

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

static volatile uint32_t ticks;

ISR(TIMER1_COMPA_vect) { ticks++; }

uint32_t board_micros(void)
{
    uint32_t t;
    uint16_t count;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        t = ticks;
        count = TCNT1;
        if ((TIFR1 & _BV(OCF1A)) && count < TICK_US) /* wrapped, interrupt not served yet */
            t++;
    }
    return t * TICK_US + count / 2u;
}

static void timebase_init(void)
{
    TCCR1A = 0;
    OCR1A = TICK_US * 2u - 1u;               /* 500 counts at 2 MHz */
    TCCR1B = _BV(WGM12) | _BV(CS11);         /* CTC on OCR1A, clk/8 */
    TIMSK1 = _BV(OCIE1A);
}

/* ---- LED PWM: timers 3, 4, 5 in fast PWM mode 14 (TOP = ICRn), clk/1 --------------------- */

typedef struct {
    volatile uint8_t *tccra;
    volatile uint16_t *ocr;
    uint8_t com1;            /* COMnx1 bit: non-inverting PWM on the pin */
    volatile uint8_t *port;
    uint8_t bit;
} pwm_channel_t;

/* Channel order = NAMES= order; the pins are board/pins_mega2560.h's (Arduino D5, D2, D3, D6, D7, D8, D46). */
#define PWM_CHANNEL(index, port, bit, arduino, timer, unit) \
    {&TCCR##timer##A, &OCR##timer##unit, COM##timer##unit##1, &PORT##port, P##port##bit},
static const pwm_channel_t channels[] = {BOOTH_LED_PINS(PWM_CHANNEL)};
#undef PWM_CHANNEL
_Static_assert(sizeof channels / sizeof channels[0] >= BOOTH_CHANNELS, "more channels than PWM outputs");

void board_set_levels(const uint16_t duty[BOOTH_CHANNELS])
{
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        const pwm_channel_t *ch = &channels[c];
        if (duty[c] == 0) {
            /* Off is off: disconnect the compare output (fast PWM at OCR 0 still spikes). */
            *ch->tccra &= (uint8_t)~_BV(ch->com1);
            *ch->port &= (uint8_t)~_BV(ch->bit);
            *ch->ocr = 0;
        } else {
            *ch->ocr = duty[c] > LEVEL_TOP ? LEVEL_TOP : duty[c];
            *ch->tccra |= _BV(ch->com1);
        }
    }
    /* In fast PWM the OCR registers are double-buffered and load at BOTTOM: up to one PWM
     * period (4.1 ms at 16 bits) late, longer than a short settle. Setting the counters to
     * TOP makes the next clock load the new duties at once (the running period is cut short). */
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        TCNT3 = LEVEL_TOP;
        TCNT4 = LEVEL_TOP;
        TCNT5 = LEVEL_TOP;
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

#define EDGE_SIZE 16u
static volatile uint8_t edge_buf[EDGE_SIZE];
static volatile uint8_t edge_head, edge_tail;

ISR(INT0_vect)
{
    uint8_t next = (uint8_t)((edge_head + 1u) & (EDGE_SIZE - 1u));
    if (next != edge_tail) {
        edge_buf[edge_head] = (uint8_t)(EXPOSURE_PIN & _BV(EXPOSURE_BIT));
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
    if (high)
        TRIGGER_PORT |= _BV(TRIGGER_BIT);
    else
        TRIGGER_PORT &= (uint8_t)~_BV(TRIGGER_BIT);
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
static const uint8_t serial_magic[2] = {'M', 'S'};

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
        booth_poll(&booth, board_micros());
        cli();
        if (rx_tail == rx_head && edge_tail == edge_head) {
            sleep_enable();
            sei(); /* the instruction after sei runs before any interrupt: no lost wake-up */
            sleep_cpu();
            sleep_disable();
        } else {
            sei();
        }
    }
}

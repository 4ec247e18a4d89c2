/* pin_model: LED pins from the firmware's register writes, per the ATmega2560 datasheet.
 * See pin_model.h for what is modelled and why. */
#include "pin_model.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define TIMERS 3
#define LOG_SIZE (1u << 16) /* edges kept per channel (a power of two) */
#define NEVER UINT64_MAX

typedef struct {
    int number;                 /* 3, 4, 5 */
    uint16_t base;              /* data address of TCCRnA */
    uint16_t port, ddr;         /* PORTx, DDRx of its OCnA/B/C pins */
    uint8_t bit[3];             /* OCnA/B/C pin bits */
    uint8_t tccra, tccrb;
    uint16_t icr, ocr[3], ocr_buf[3];
    uint8_t temp;               /* the TEMP register of 16-bit accesses */
    uint16_t tcnt;              /* value since cycle `at` */
    avr_cycle_count_t at;
    int blocked;                /* a TCNT write blocks the compare match of the next timer clock */
    int idle;                   /* at a fixed point (TOP 0, nothing buffered): no event until a write */
    uint8_t latch[3];           /* the OCnx registers of the waveform generator */
    avr_cycle_count_t next;     /* cycle of the next clock with an event */
} timer_t_;

typedef struct {
    avr_cycle_count_t cycle[LOG_SIZE];
    int64_t cum[LOG_SIZE];      /* high cycles before cycle[i] */
    uint8_t level[LOG_SIZE];
    uint32_t count;             /* edges logged (the newest is (count - 1) % LOG_SIZE) */
} edge_log_t;

static avr_t *avr;
static timer_t_ timers[TIMERS];
static edge_log_t logs[PM_CHANNELS];
static double levels[PM_CHANNELS];
static avr_cycle_count_t changed_at;
static int warned_mode[TIMERS], warned_clock[TIMERS];
void (*pin_model_tcnt_hook)(int timer, avr_cycle_count_t cycle);

static const int prescale[8] = {0, 1, 8, 64, 256, 1024, 0, 0};

static int wgm(const timer_t_ *t) { return ((t->tccrb >> 3) & 3) << 2 | (t->tccra & 3); }
static int is_pwm(const timer_t_ *t) { return wgm(t) == 14 || wgm(t) == 15; }
static int com(const timer_t_ *t, int ch) { return (t->tccra >> (6 - 2 * ch)) & 3; }
static int supported(const timer_t_ *t)
{
    int m = wgm(t);
    return m == 0 || m == 4 || m == 12 || m == 14 || m == 15;
}

static int division(timer_t_ *t)
{
    int cs = t->tccrb & 7;
    int i = (int)(t - timers);
    if (cs >= 6 && !warned_clock[i]) {
        fprintf(stderr, "booth_sim: timer%d clocked from its Tn pin: not modelled (stopped)\n", t->number);
        warned_clock[i] = 1;
    }
    if (cs && !supported(t)) {
        if (!warned_mode[i])
            fprintf(stderr, "booth_sim: timer%d in waveform mode %d: not modelled (stopped)\n", t->number, wgm(t));
        warned_mode[i] = 1;
        return 0;
    }
    return prescale[cs];
}

static uint16_t top(const timer_t_ *t)
{
    switch (wgm(t)) {
    case 4:
    case 15:
        return t->ocr[0];
    case 12:
    case 14:
        return t->icr;
    default:
        return 0xFFFF;
    }
}

/* The pin is driven by the waveform generator (else by its port bit). */
static int connected(const timer_t_ *t, int ch)
{
    int c = com(t, ch);
    if (c == 0)
        return 0;
    if (c == 1 && is_pwm(t))
        return ch == 0; /* table 17-4: COMnA = 1 in modes 14, 15 toggles OCnA; OCnB/C stay disconnected */
    return 1;
}

/* ---- the edge log ---------------------------------------------------------------------- */

static void log_level(int channel, avr_cycle_count_t cycle, int level)
{
    edge_log_t *g = &logs[channel];
    if (g->count) {
        uint32_t last = (g->count - 1) & (LOG_SIZE - 1);
        if (g->level[last] == level)
            return;
        if (cycle < g->cycle[last])
            cycle = g->cycle[last];
        int64_t cum = g->cum[last] + (g->level[last] ? (int64_t)(cycle - g->cycle[last]) : 0);
        uint32_t i = g->count & (LOG_SIZE - 1);
        g->cycle[i] = cycle;
        g->cum[i] = cum;
        g->level[i] = (uint8_t)level;
    } else {
        g->cycle[0] = cycle;
        g->cum[0] = 0;
        g->level[0] = (uint8_t)level;
    }
    g->count++;
}

static int pin_of(const timer_t_ *t, int ch)
{
    uint8_t mask = (uint8_t)(1u << t->bit[ch]);
    if (!(avr->data[t->ddr] & mask))
        return 0; /* an input: the LED driver's input is not driven (a pull-down keeps it off) */
    return connected(t, ch) ? t->latch[ch] : (avr->data[t->port] & mask) != 0;
}

static void update_pins(timer_t_ *t, avr_cycle_count_t cycle)
{
    for (int ch = 0; ch < 3; ch++)
        log_level((int)(t - timers) * 3 + ch, cycle, pin_of(t, ch));
}

/* ---- the counter ----------------------------------------------------------------------- */

/* The first timer clock after `cycle` (clocks at multiples of the division). */
static avr_cycle_count_t next_clock(avr_cycle_count_t cycle, int div) { return (cycle / div + 1) * div; }

static void compare_action(timer_t_ *t, int ch)
{
    int c = com(t, ch);
    if (is_pwm(t)) {
        if (c == 2)
            t->latch[ch] = 0;
        else if (c == 3)
            t->latch[ch] = 1;
        else if (c == 1 && ch == 0)
            t->latch[ch] ^= 1;
    } else if (c == 1) {
        t->latch[ch] ^= 1;
    } else if (c == 2) {
        t->latch[ch] = 0;
    } else if (c == 3) {
        t->latch[ch] = 1;
    }
}

static void schedule(timer_t_ *t)
{
    int div = division(t);
    t->next = NEVER;
    if (!div || t->idle)
        return;
    uint16_t v = t->tcnt, tp = top(t);
    uint32_t maxv = v <= tp ? tp : 0xFFFF;
    uint32_t k = maxv - v + 1; /* clocks to the one leaving maxv (to BOTTOM) */
    for (int ch = 0; ch < 3; ch++) {
        uint16_t o = t->ocr[ch];
        if (com(t, ch) == 0 || o < v || o > maxv || (o == v && t->blocked))
            continue;
        if ((uint32_t)(o - v + 1) < k)
            k = o - v + 1;
    }
    t->next = next_clock(t->at, div) + (avr_cycle_count_t)(k - 1) * div;
}

/* The timer clock at t->next: TCNT leaves its value; compare matches, then BOTTOM. */
static void step(timer_t_ *t)
{
    int div = division(t);
    avr_cycle_count_t when = t->next;
    uint32_t clocks = (uint32_t)((when - next_clock(t->at, div)) / div); /* clocks before this one */
    uint16_t v = (uint16_t)(t->tcnt + clocks);
    if (clocks)
        t->blocked = 0;
    uint16_t tp = top(t);
    for (int ch = 0; ch < 3; ch++)
        if (v == t->ocr[ch] && !t->blocked)
            compare_action(t, ch);
    uint16_t n = v == tp ? 0 : (uint16_t)(v + 1);
    int unchanged = 1;
    if (n == 0 && is_pwm(t)) {
        for (int ch = 0; ch < 3; ch++) {
            if (t->ocr[ch] != t->ocr_buf[ch])
                unchanged = 0;
            t->ocr[ch] = t->ocr_buf[ch]; /* double buffered: loaded at BOTTOM */
            if (com(t, ch) == 2)
                t->latch[ch] = 1;
            else if (com(t, ch) == 3)
                t->latch[ch] = 0;
        }
    }
    t->tcnt = n;
    t->at = when;
    t->blocked = 0;
    update_pins(t, when);
    /* TOP 0 and nothing left to load: every later clock repeats this one (a one-shot at rest). */
    t->idle = tp == 0 && v == 0 && n == 0 && unchanged;
    schedule(t);
}

static void advance(timer_t_ *t, avr_cycle_count_t until)
{
    while (t->next <= until)
        step(t);
}

/* TCNT now (no event is due before `now`: advance first). */
static void rebase(timer_t_ *t, avr_cycle_count_t now)
{
    int div = division(t);
    if (div && now > t->at && !t->idle) {
        avr_cycle_count_t first = next_clock(t->at, div);
        if (now >= first) {
            uint32_t clocks = (uint32_t)((now - first) / div) + 1;
            t->tcnt = (uint16_t)(t->tcnt + clocks);
            t->blocked = 0;
        }
    }
    t->at = now;
}

/* ---- register writes --------------------------------------------------------------------- */

static double level_of(const timer_t_ *t, int ch)
{
    uint8_t mask = (uint8_t)(1u << t->bit[ch]);
    if (!(avr->data[t->ddr] & mask))
        return 0.0;
    if (!connected(t, ch))
        return (avr->data[t->port] & mask) ? 1.0 : 0.0;
    uint16_t tp = top(t);
    if (!is_pwm(t) || !prescale[t->tccrb & 7] || tp == 0)
        return t->latch[ch];
    uint16_t o = t->ocr_buf[ch]; /* what the next period shows */
    double period = (double)tp + 1.0;
    if (com(t, ch) == 2)
        return o >= tp ? 1.0 : (o + 1.0) / period;
    if (com(t, ch) == 3)
        return o >= tp ? 0.0 : (tp - o) / period;
    return 0.5; /* COMnA = 1: OCnA toggles on compare, half duty */
}

static void refresh_levels(avr_cycle_count_t now)
{
    (void)now;
    for (int i = 0; i < TIMERS; i++)
        for (int ch = 0; ch < 3; ch++) {
            levels[i * 3 + ch] = level_of(&timers[i], ch);
        }
}

static void timer_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    timer_t_ *t = param;
    avr_cycle_count_t now = a->cycle;
    advance(t, now);
    rebase(t, now);
    a->data[addr] = v;
    int offset = addr - t->base;
    switch (offset) {
    case 0: /* TCCRnA */
        t->tccra = v;
        break;
    case 1: /* TCCRnB */
        t->tccrb = v;
        break;
    case 2: /* TCCRnC: force output compare, non-PWM modes only; reads as zero */
        if (!is_pwm(t))
            for (int ch = 0; ch < 3; ch++)
                if (v & (0x80 >> ch))
                    compare_action(t, ch);
        a->data[addr] = 0;
        break;
    case 4: /* TCNTnL: the 16-bit write */
        t->tcnt = (uint16_t)(t->temp << 8 | v);
        t->blocked = 1;
        if (pin_model_tcnt_hook)
            pin_model_tcnt_hook(t->number, now);
        break;
    case 6: /* ICRnL: not double buffered */
        t->icr = (uint16_t)(t->temp << 8 | v);
        break;
    case 8:
    case 10:
    case 12: { /* OCRnxL */
        int ch = (offset - 8) / 2;
        uint16_t value = (uint16_t)(t->temp << 8 | v);
        t->ocr_buf[ch] = value;
        if (!is_pwm(t))
            t->ocr[ch] = value;
    } break;
    case 5:
    case 7:
    case 9:
    case 11:
    case 13: /* high bytes go to TEMP */
        t->temp = v;
        break;
    default:
        break;
    }
    t->idle = 0;
    if (offset != 4 && offset != 5) /* a TCNT write starts pulses; anything else reconfigures */
        changed_at = now;
    update_pins(t, now);
    schedule(t);
    refresh_levels(now);
}

/* Port and DDR writes: simavr's own handler, then the pins of the channels on that port. */
typedef struct {
    avr_io_write_t original;
    void *param;
} chained_t;

static chained_t chained[0x140];

static void port_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    chained_t *c = &chained[addr];
    if (c->original)
        c->original(a, addr, v, c->param);
    else
        a->data[addr] = v;
    for (int i = 0; i < TIMERS; i++) {
        if (timers[i].port == addr || timers[i].ddr == addr) {
            advance(&timers[i], a->cycle);
            update_pins(&timers[i], a->cycle);
            changed_at = a->cycle;
        }
    }
    refresh_levels(a->cycle);
}

static void mask_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    if (v)
        fprintf(stderr, "booth_sim: TIMSK at 0x%02X = 0x%02X: timer 3..5 interrupts are not modelled\n", addr, v);
    a->data[addr] = v;
}

static void take_write(uint16_t addr, avr_io_write_t handler, void *param)
{
    int io = AVR_DATA_TO_IO(addr);
    avr->io[io].w.c = handler;
    avr->io[io].w.param = param;
}

static void chain_write(uint16_t addr)
{
    int io = AVR_DATA_TO_IO(addr);
    chained[addr].original = avr->io[io].w.c;
    chained[addr].param = avr->io[io].w.param;
    take_write(addr, port_write, NULL);
}

void pin_model_install(avr_t *a)
{
    static const struct {
        int number;
        uint16_t base, port, ddr, timsk;
    } layout[TIMERS] = {{3, 0x90, 0x2E, 0x2D, 0x71}, {4, 0xA0, 0x102, 0x101, 0x72}, {5, 0x120, 0x10B, 0x10A, 0x73}};
    avr = a;
    memset(timers, 0, sizeof timers);
    for (int i = 0; i < TIMERS; i++) {
        timer_t_ *t = &timers[i];
        t->number = layout[i].number;
        t->base = layout[i].base;
        t->port = layout[i].port;
        t->ddr = layout[i].ddr;
        t->bit[0] = 3, t->bit[1] = 4, t->bit[2] = 5;
        t->next = NEVER;
        for (int r = 0; r < 14; r++)
            if (r != 3) /* 0x?3 is reserved */
                take_write((uint16_t)(t->base + r), timer_write, t);
        take_write(layout[i].timsk, mask_write, NULL);
        chain_write(t->port);
        chain_write(t->ddr);
    }
    for (int c = 0; c < PM_CHANNELS; c++) {
        logs[c].count = 0;
        log_level(c, 0, 0);
        levels[c] = 0.0;
    }
}

void pin_model_reset(void)
{
    for (int i = 0; i < TIMERS; i++) {
        timer_t_ *t = &timers[i];
        t->tccra = t->tccrb = 0;
        t->icr = t->tcnt = 0;
        memset(t->ocr, 0, sizeof t->ocr);
        memset(t->ocr_buf, 0, sizeof t->ocr_buf);
        memset(t->latch, 0, sizeof t->latch);
        t->temp = 0;
        t->at = avr->cycle;
        t->blocked = t->idle = 0;
        t->next = NEVER;
        update_pins(t, avr->cycle);
    }
    refresh_levels(avr->cycle);
}

void pin_model_advance(void)
{
    for (int i = 0; i < TIMERS; i++)
        advance(&timers[i], avr->cycle);
}

int pin_model_pin(int channel)
{
    const edge_log_t *g = &logs[channel];
    return g->level[(g->count - 1) & (LOG_SIZE - 1)];
}

double pin_model_level(int channel) { return levels[channel]; }

avr_cycle_count_t pin_model_changed_at(void) { return changed_at; }

/* High cycles before `when` (when within the log). */
static int64_t cumulative(const edge_log_t *g, avr_cycle_count_t when)
{
    uint32_t oldest = g->count > LOG_SIZE ? g->count - LOG_SIZE : 0;
    uint32_t lo = oldest, hi = g->count - 1; /* the last edge at or before `when` */
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo + 1) / 2;
        if (g->cycle[mid & (LOG_SIZE - 1)] <= when)
            lo = mid;
        else
            hi = mid - 1;
    }
    uint32_t i = lo & (LOG_SIZE - 1);
    return g->cum[i] + (g->level[i] ? (int64_t)(when - g->cycle[i]) : 0);
}

int64_t pin_model_on_cycles(int channel, avr_cycle_count_t from, avr_cycle_count_t to)
{
    const edge_log_t *g = &logs[channel];
    uint32_t oldest = g->count > LOG_SIZE ? g->count - LOG_SIZE : 0;
    if (to > avr->cycle || from > to || (oldest && from < g->cycle[oldest & (LOG_SIZE - 1)]))
        return -1;
    pin_model_advance();
    return cumulative(g, to) - cumulative(g, from);
}

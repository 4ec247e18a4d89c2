/* The booth protocol and sequencer, written from docs/booth-protocol.md and kept to the
 * behaviour of the Python emulator (led_controller/emulator.py), which is the reference:
 * same checks in the same order, same error texts. Plain C99, no AVR headers. */
#include "booth_core.h"

#include <string.h>

#define LEVEL_TOP ((uint16_t)((1ul << BOOTH_LEVEL_BITS) - 1u))
#define WATCHDOG_MIN_MS 50u
#define WATCHDOG_MAX_MS 600000ul

/* ---- CRC-16/CCITT-FALSE, bitwise (small; a 512-byte table buys nothing at 115200 baud) -- */

static uint16_t crc_update(uint16_t crc, const uint8_t *data, uint16_t len)
{
    while (len--) {
        crc ^= (uint16_t)(*data++) << 8;
        for (uint8_t bit = 0; bit < 8; bit++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

uint16_t booth_crc16(const uint8_t *data, uint16_t len) { return crc_update(0xFFFF, data, len); }

/* ---- output: frames built in one buffer ------------------------------------------------ */

typedef struct {
    char buf[BOOTH_OUT_MAX];
    uint16_t len;
} out_t;

/* Constant text (in flash: BOOTH_TEXT). */
static void put_text(out_t *o, booth_text_t s)
{
    while (*s && o->len < BOOTH_OUT_MAX - 8)
        o->buf[o->len++] = *s++;
}
#define PUT(o, literal) put_text((o), BOOTH_TEXT(literal))

/* A received word (RAM) against a constant text (flash): starting with it, or equal to it. */
static bool starts_with(const char *word, booth_text_t text)
{
    while (*text)
        if (*word++ != *text++)
            return false;
    return true;
}

static bool text_is(const char *word, booth_text_t text)
{
    while (*text)
        if (*word++ != *text++)
            return false;
    return *word == '\0';
}
#define IS(word, literal) text_is((word), BOOTH_TEXT(literal))

/* Text in RAM (the serial, a command's name, digits). */
static void put_ram(out_t *o, const char *s)
{
    while (*s && o->len < BOOTH_OUT_MAX - 8)
        o->buf[o->len++] = *s++;
}

static void put_n(out_t *o, const char *s, uint16_t n)
{
    while (n-- && *s && o->len < BOOTH_OUT_MAX - 8)
        o->buf[o->len++] = *s++;
}

static void hex_into(char *to, uint32_t v, uint8_t digits)
{
    while (digits--) {
        uint8_t d = (uint8_t)((v >> (4 * digits)) & 0xF);
        *to++ = (char)(d < 10 ? '0' + d : 'A' - 10 + d);
    }
}

static void put_hex(out_t *o, uint32_t v, uint8_t digits)
{
    hex_into(o->buf + o->len, v, digits);
    o->len = (uint16_t)(o->len + digits);
}

static void put_u32(out_t *o, uint32_t v)
{
    char tmp[11];
    uint8_t n = 0;
    do {
        tmp[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    while (n)
        o->buf[o->len++] = tmp[--n];
}

static void put_i32(out_t *o, int32_t v)
{
    if (v < 0) {
        o->buf[o->len++] = '-';
        put_u32(o, (uint32_t)(-(v + 1)) + 1u);
    } else {
        put_u32(o, (uint32_t)v);
    }
}

/* The whole frame into `to` (room for body->len + 14 bytes); returns its length. */
static uint16_t frame_into(char *to, char mark, uint8_t seq, const out_t *body)
{
    to[0] = mark;
    hex_into(to + 1, seq, 2);
    to[3] = ':';
    hex_into(to + 4, body->len, 3);
    to[7] = ':';
    memcpy(to + 8, body->buf, body->len);
    uint16_t n = (uint16_t)(8 + body->len);
    uint16_t crc = booth_crc16((const uint8_t *)to, n);
    to[n] = '*';
    hex_into(to + n + 1, crc, 4);
    to[n + 5] = '\n';
    return (uint16_t)(n + 6);
}

/* Frame `body` (already in body->buf) with mark and seq and send it: header, body and checksum
 * go out in turn (no frame-sized copy: that RAM holds the steps' exposures instead). */
static void send_frame(char mark, uint8_t seq, const out_t *body)
{
    char head[8];
    head[0] = mark;
    hex_into(head + 1, seq, 2);
    head[3] = ':';
    hex_into(head + 4, body->len, 3);
    head[7] = ':';
    uint16_t crc = crc_update(crc_update(0xFFFF, (const uint8_t *)head, 8), (const uint8_t *)body->buf, body->len);
    board_write(head, 8);
    board_write(body->buf, body->len);
    head[0] = '*';
    hex_into(head + 1, crc, 4);
    head[5] = '\n';
    board_write(head, 6);
}

/* The booth's serial, or '-' when never set. */
static void put_serial(out_t *o, const booth_t *b)
{
    if (b->serial[0])
        put_ram(o, b->serial);
    else
        PUT(o, "-");
}

static void send_event(booth_t *b, const out_t *body)
{
    b->event_seq = (uint8_t)(b->event_seq % 255u + 1u);
    send_frame('!', b->event_seq, body);
}

/* ---- LEDs ------------------------------------------------------------------------------ */

static void drive(booth_t *b)
{
    board_set_levels(b->duty);
}

static void leds_off(booth_t *b)
{
    memset(b->duty, 0, sizeof b->duty);
    drive(b);
}

static bool any_on(const booth_t *b)
{
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++)
        if (b->duty[c])
            return true;
    return false;
}

static bool is_held(const booth_t *b, uint16_t i) { return b->held[i >> 3] & (1u << (i & 7)); }

static void set_held(booth_t *b, uint16_t i, bool held)
{
    if (held)
        b->held[i >> 3] |= (uint8_t)(1u << (i & 7));
    else
        b->held[i >> 3] &= (uint8_t)~(1u << (i & 7));
}

static bool due(uint32_t now_us, uint32_t when_us) { return (int32_t)(now_us - when_us) >= 0; }

/* ---- pulse dimming: a step's exposure and its pulses (docs/booth-firmware.md, section 2) ---- */

#define CYCLES_PER_US ((uint32_t)(BOOTH_CLOCK_HZ / 1000000ul))
#define PULSE_TICKS_MAX 65535ul /* one lap of a 16-bit timer */

uint16_t booth_exposure_code(uint32_t exposure_us)
{
    if (exposure_us < 4096u)
        return (uint16_t)exposure_us;
    uint8_t e = 1;
    while ((exposure_us >> e) >= 4096u)
        e++;
    uint32_t m = (exposure_us + (1ul << (e - 1))) >> e; /* rounded half up */
    if (m >= 4096u) {
        e++;
        m = (exposure_us + (1ul << (e - 1))) >> e;
    }
    return (uint16_t)((uint16_t)e << 12 | m);
}

uint32_t booth_exposure_us(uint16_t code) { return (uint32_t)(code & 0x0FFFu) << (code >> 12); }

static const BOOTH_FLASH uint16_t prescalers[5] = {1, 8, 64, 256, 1024};

bool booth_pulse_plan(const booth_t *b, const uint16_t duty[BOOTH_CHANNELS], uint16_t code, bool camera,
                      booth_pulses_t *plan)
{
    uint32_t exposure_us = booth_exposure_us(code);
    uint8_t k = 0;
    if (!code)
        return false;
    while (k < 5 && exposure_us * CYCLES_PER_US > PULSE_TICKS_MAX * prescalers[k])
        k++;
    if (k == 5)
        return false; /* longer than one lap at clk/1024 (4.19 s): PWM (off by < 0.1 %) */
    uint32_t p = prescalers[k];
    uint32_t ticks = exposure_us * CYCLES_PER_US / p; /* exact: see booth_exposure_code */
    uint32_t margin = (BOOTH_PULSE_MARGIN_US * CYCLES_PER_US + p - 1) / p + 1;
    uint32_t roll = (b->roll_us * CYCLES_PER_US + p - 1) / p;
    if (ticks < roll + margin + 3)
        return false; /* no room for a pulse in the flash window: PWM */
    uint32_t cap = ticks - roll - margin - 2;
    plan->clock_select = (uint8_t)(k + 1);
    plan->on_exposure_input = camera;
    /* CAMERA: from the flash window's start, ending `margin` before its end; BOOTH: from the
     * trigger, ending a microsecond and a tick before the exposure would (zero camera latency). */
    plan->window = (uint16_t)(camera ? ticks - roll - margin : ticks - (CYCLES_PER_US + p - 1) / p - 1);
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        if (duty[c] == 0) {
            plan->width[c] = 0;
        } else if (duty[c] >= LEVEL_TOP) {
            plan->width[c] = BOOTH_PULSE_FULL;
        } else {
            uint32_t w = ((uint32_t)duty[c] * ticks + LEVEL_TOP / 2u) / LEVEL_TOP;
            plan->width[c] = (uint16_t)(w < cap ? w : cap);
        }
    }
    return true;
}

/* " ON=<us>,<us>,…": each LED's on-time per exposure, exact (the exposure itself when on throughout). */
static void put_on_times(out_t *o, const booth_pulses_t *plan, uint16_t code)
{
    PUT(o, " ON=");
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        uint32_t cycles = plan->width[c] == BOOTH_PULSE_FULL
                              ? booth_exposure_us(code) * CYCLES_PER_US
                              : (uint32_t)plan->width[c] * prescalers[plan->clock_select - 1];
        if (c)
            PUT(o, ",");
        put_u32(o, cycles / CYCLES_PER_US);
        uint32_t frac = (cycles % CYCLES_PER_US) * (10000ul / CYCLES_PER_US); /* 1/16 us = 0.0625 */
        if (frac) {
            char digits[5];
            uint8_t n = 4;
            digits[4] = '\0';
            while (n--) {
                digits[n] = (char)('0' + frac % 10);
                frac /= 10;
            }
            for (n = 4; n > 0 && digits[n - 1] == '0'; n--)
                digits[n - 1] = '\0';
            PUT(o, ".");
            put_ram(o, digits);
        }
    }
}

/* The LEDs for table step `index` (b->duty holds its levels): pulses in BOOTH and CAMERA mode for
 * a step with an exposure, PWM otherwise. */
static void drive_step(booth_t *b, uint16_t index)
{
    booth_pulses_t plan;
    if ((b->mode == MODE_BOOTH || b->mode == MODE_CAMERA) &&
        booth_pulse_plan(b, b->duty, b->exposure[index], b->mode == MODE_CAMERA, &plan))
        board_set_pulses(&plan);
    else
        drive(b);
}

/* ---- sequencing (as BoothEmulator._apply_step, _release_hold, _finish, _all_off) -------- */

static void trigger_low(booth_t *b)
{
    b->pulse_high = false;
    board_trigger_out(false); /* also cancels a pulse the board has scheduled */
}

void booth_all_off(booth_t *b)
{
    leds_off(b);
    trigger_low(b);
    b->holding = false;
    b->action = ACTION_NONE;
    if (b->state == STATE_ARMED || b->state == STATE_RUNNING)
        b->state = STATE_IDLE;
}

static bool apply_step(booth_t *b, uint16_t index)
{
    b->step = index;
    if (is_held(b, index)) {
        b->holding = true;
        leds_off(b);
        return false;
    }
    b->holding = false;
    memcpy(b->duty, b->table[index], sizeof b->duty);
    drive_step(b, index);
    return true;
}

/* The pulse never comes before settle_us after the LEDs actually changed (a late apply,
 * e.g. behind a long frame, shortens nothing; the period grid stays). */
static void settle_from_now(booth_t *b)
{
    uint32_t earliest = board_micros() + b->settle_us;
    if ((int32_t)(b->action_due_us - earliest) < 0)
        b->action_due_us = earliest;
}

static void release_hold(booth_t *b, uint32_t now_us)
{
    (void)now_us;
    b->holding = false;
    memcpy(b->duty, b->table[b->step], sizeof b->duty);
    drive_step(b, (uint16_t)b->step);
    if (b->mode == MODE_BOOTH) {
        /* The step's slot starts now; later steps keep the period from here. */
        uint32_t applied = board_micros();
        b->t0_us = applied - (uint32_t)b->step * b->period_us;
        b->action = ACTION_PULSE;
        b->action_due_us = applied + b->settle_us;
        board_trigger_pulse(b->action_due_us, b->pulse_us);
    }
}

static void finish(booth_t *b)
{
    out_t o = {.len = 0};
    leds_off(b);
    b->state = STATE_DONE;
    b->holding = false;
    b->action = ACTION_NONE;
    PUT(&o, "DONE ");
    put_u32(&o, b->triggers);
    send_event(b, &o);
}

/* CAMERA: the exposure is over (and, with ROLL, its last row): the next step, or done. */
static void advance_camera(booth_t *b)
{
    if ((uint16_t)(b->step + 1) >= b->steps)
        finish(b);
    else
        apply_step(b, (uint16_t)(b->step + 1));
}

static void run_action(booth_t *b, uint32_t now_us)
{
    if (b->action == ACTION_ADVANCE) {
        b->action = ACTION_NONE;
        advance_camera(b);
    } else if (b->action == ACTION_APPLY) {
        uint16_t index = (uint16_t)(b->step + 1);
        if (index >= b->steps) {
            finish(b);
            return;
        }
        if (!apply_step(b, index)) {
            b->action = ACTION_NONE; /* held: PSET resumes the sequence */
            return;
        }
        b->action = ACTION_PULSE;
        b->action_due_us = b->t0_us + (uint32_t)index * b->period_us + b->settle_us;
        settle_from_now(b);
        /* Both edges (and the LED pulses with the first) on the board's timer, not this loop. */
        board_trigger_pulse(b->action_due_us, b->pulse_us);
    } else {
        out_t o = {.len = 0};
        (void)now_us;
        b->triggers++;
        /* The board pulsed the trigger at action_due_us; now its report. */
        PUT(&o, "TRIG ");
        put_u32(&o, b->triggers);
        PUT(&o, " ");
        put_i32(&o, b->step);
        send_event(b, &o);
        b->action = ACTION_APPLY;
        b->action_due_us = b->t0_us + (uint32_t)(b->step + 1) * b->period_us;
    }
}

void booth_exposure(booth_t *b, bool active, uint32_t now_us)
{
    if (b->state != STATE_RUNNING || b->mode != MODE_CAMERA)
        return;
    if (active) {
        out_t o = {.len = 0};
        b->triggers++;
        PUT(&o, "TRIG ");
        put_u32(&o, b->triggers);
        PUT(&o, " ");
        if (b->holding)
            PUT(&o, "HOLD"); /* never the step's index: its levels were not shown */
        else
            put_i32(&o, b->step);
        send_event(b, &o);
    } else if (b->roll_us) {
        /* A rolling shutter's flash window ends as its first row does: the last row still exposes. */
        b->action = ACTION_ADVANCE;
        b->action_due_us = now_us + b->roll_us;
    } else {
        advance_camera(b);
    }
}

/* Wake the main loop when the next timed action is due. */
static void wake_for(booth_t *b)
{
    if (b->action != ACTION_NONE)
        board_wake_at(b->action_due_us);
}

void booth_poll(booth_t *b, uint32_t now_us)
{
    while (b->action != ACTION_NONE && due(now_us, b->action_due_us))
        run_action(b, now_us);
    if (b->watchdog_ms && !b->watchdog_tripped &&
        now_us - b->last_host_us >= b->watchdog_ms * 1000ul) {
        b->watchdog_tripped = true;
        if (any_on(b) || b->state == STATE_ARMED || b->state == STATE_RUNNING) {
            out_t o = {.len = 0};
            booth_all_off(b);
            PUT(&o, "WDOG");
            send_event(b, &o);
        }
    }
    wake_for(b);
}

/* ---- boot banner ----------------------------------------------------------------------- */

/* A line end first: whatever the reset left on the line (a half frame, bootloader noise) is then
 * a line of its own, and the banner a clean frame. */
static void booth_banner(booth_t *b)
{
    out_t o = {.len = 0};
    char line_end = '\n';
    board_write(&line_end, 1);
    PUT(&o, "BOOT FW=" BOOTH_FIRMWARE " PROTO=1");
    send_event(b, &o);
}

void booth_init(booth_t *b, uint32_t now_us)
{
    memset(b, 0, sizeof *b);
    b->state = STATE_IDLE;
    b->mode = MODE_NONE;
    b->step = -1;
    b->watchdog_ms = BOOTH_WATCHDOG_MS;
    b->last_host_us = now_us;
    leds_off(b);
    board_trigger_out(false);
    board_serial_load(b->serial);
    b->serial[BOOTH_SERIAL_MAX] = '\0';
    booth_banner(b);
}

/* ---- commands ------------------------------------------------------------------------ */

/* The refusal codes (protocol section 4), in flash. */
static const BOOTH_FLASH char E_ARG[] = "E_ARG";
static const BOOTH_FLASH char E_STATE[] = "E_STATE";
static const BOOTH_FLASH char E_RANGE[] = "E_RANGE";
static const BOOTH_FLASH char E_FULL[] = "E_FULL";
static const BOOTH_FLASH char E_CMD[] = "E_CMD";
static const BOOTH_FLASH char E_FRAME[] = "E_FRAME";
static const BOOTH_FLASH char E_CRC[] = "E_CRC";
static const BOOTH_FLASH char E_LEN[] = "E_LEN";

typedef struct {
    booth_text_t code;
    booth_text_t text;
} refusal_t;

static const refusal_t *refused; /* set by a command that refuses */
static refusal_t refusal_buf;

#define REFUSE(code, literal) refuse((code), BOOTH_TEXT(literal))
static bool refuse(booth_text_t code, booth_text_t text)
{
    refusal_buf.code = code;
    refusal_buf.text = text;
    refused = &refusal_buf;
    return false;
}

static bool is_hex_text(const char *s, uint16_t n)
{
    if (!n)
        return false;
    for (uint16_t i = 0; i < n; i++)
        if (!((s[i] >= '0' && s[i] <= '9') || (s[i] >= 'A' && s[i] <= 'F')))
            return false;
    return true;
}

static uint32_t hex_value(const char *s, uint16_t n)
{
    uint32_t v = 0;
    for (uint16_t i = 0; i < n; i++)
        v = (v << 4) | (uint32_t)(s[i] <= '9' ? s[i] - '0' : s[i] - 'A' + 10);
    return v;
}

/* Decimal digits only, 1..max_digits of them (Python's isdigit and a length bound). */
static bool decimal(const char *s, uint8_t max_digits, uint32_t *value)
{
    uint32_t v = 0;
    uint8_t n = 0;
    for (; *s; s++, n++) {
        if (*s < '0' || *s > '9' || n >= max_digits)
            return false;
        v = v * 10u + (uint32_t)(*s - '0');
    }
    *value = v;
    return n > 0;
}

typedef struct {
    const char *w[BOOTH_MAX_WORDS];
    uint16_t n; /* the true word count, also beyond BOOTH_MAX_WORDS */
} words_t;

static bool no_args(const words_t *a)
{
    return a->n == 0 ? true : REFUSE(E_ARG, "takes no arguments");
}

/* Levels: exactly BOOTH_CHANNELS words of 4 upper-case hex digits, from a->w[first]. */
static bool levels_arg(const words_t *a, uint16_t first, uint16_t count, uint16_t out[BOOTH_CHANNELS])
{
    if (count != BOOTH_CHANNELS)
        return REFUSE(E_ARG, "needs " BOOTH_CHANNELS_TEXT " levels");
    for (uint16_t i = 0; i < count; i++)
        if (strlen(a->w[first + i]) != 4 || !is_hex_text(a->w[first + i], 4))
            return REFUSE(E_ARG, "levels are 4 hex digits");
    for (uint16_t i = 0; i < count; i++) /* keep the top BITS bits, as the PWM does */
        out[i] = (uint16_t)(hex_value(a->w[first + i], 4) >> (16 - BOOTH_LEVEL_BITS));
    return true;
}

static bool editable(const booth_t *b)
{
    return (b->state == STATE_ARMED || b->state == STATE_RUNNING) ? REFUSE(E_STATE, "table in use") : true;
}

static const BOOTH_FLASH char state_names[][8] = {"IDLE", "ARMED", "RUNNING", "DONE"};
static const BOOTH_FLASH char mode_names[][7] = {"-", "HOST", "BOOTH", "CAMERA"};

/* The PWM frequency at clk/1 and TOP = 2^BITS - 1, exactly (F_CPU 16 MHz). */
#if BOOTH_CLOCK_HZ != 16000000ul
#error "PWMHZ text below assumes a 16 MHz clock"
#endif
#if BOOTH_LEVEL_BITS == 16
#define PWM_HZ_TEXT "244.140625"
#elif BOOTH_LEVEL_BITS == 15
#define PWM_HZ_TEXT "488.28125"
#elif BOOTH_LEVEL_BITS == 14
#define PWM_HZ_TEXT "976.5625"
#elif BOOTH_LEVEL_BITS == 13
#define PWM_HZ_TEXT "1953.125"
#else
#define PWM_HZ_TEXT "3906.25"
#endif

/* The ID reply's dimming words: pulses where the booth sees the exposure, PWM otherwise. */
static void put_dimming(out_t *o) { PUT(o, " DIM=PULSE PWMHZ=" PWM_HZ_TEXT); }

static bool cmd_id(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return false;
    PUT(o, " FW=" BOOTH_FIRMWARE " PROTO=1 CH=" BOOTH_CHANNELS_TEXT " NAMES=" BOOTH_NAMES
               " PEAKS=" BOOTH_PEAKS " BITS=");
    put_u32(o, BOOTH_LEVEL_BITS);
    PUT(o, " STEPS=");
    put_u32(o, BOOTH_MAX_STEPS);
    put_dimming(o);
    PUT(o, " SERIAL=");
    put_serial(o, b);
    return true;
}

static bool cmd_set(booth_t *b, const words_t *a, out_t *o)
{
    uint16_t duty[BOOTH_CHANNELS];
    (void)o;
    if (!levels_arg(a, 0, a->n, duty))
        return false;
    if (b->state == STATE_RUNNING && (b->mode == MODE_BOOTH || b->mode == MODE_CAMERA))
        return REFUSE(E_STATE, "sequence running");
    memcpy(b->duty, duty, sizeof duty);
    drive(b);
    return true;
}

static bool cmd_off(booth_t *b, const words_t *a, out_t *o)
{
    (void)o;
    if (!no_args(a))
        return false;
    booth_all_off(b);
    return true;
}

static bool cmd_pclr(booth_t *b, const words_t *a, out_t *o)
{
    (void)o;
    if (!no_args(a) || !editable(b))
        return false;
    b->steps = 0;
    memset(b->held, 0, sizeof b->held);
    return true;
}

/* An optional "EXP=<us>" word at w[at] (at < n): strips it (n - 1) and checks its value. */
static bool is_exposure_word(const char *w) { return starts_with(w, BOOTH_TEXT("EXP=")); }

static bool exposure_arg(const char *w, uint16_t *code)
{
    uint32_t us;
    if (!decimal(w + 4, 8, &us))
        return REFUSE(E_ARG, "EXP=<microseconds>");
    if (us == 0)
        return REFUSE(E_RANGE, "exposure 1..99999999 us");
    *code = booth_exposure_code(us);
    return true;
}

/* A step given an exposure: " ON=…" when BOOTH and CAMERA mode pulse it. */
static void put_step_pulses(const booth_t *b, out_t *o, const uint16_t duty[BOOTH_CHANNELS], uint16_t code)
{
    booth_pulses_t plan;
    if (booth_pulse_plan(b, duty, code, false, &plan))
        put_on_times(o, &plan, code);
}

static bool cmd_padd(booth_t *b, const words_t *a, out_t *o)
{
    uint16_t duty[BOOTH_CHANNELS];
    uint16_t count = a->n, code = 0;
    bool held = count > BOOTH_CHANNELS && count <= BOOTH_MAX_WORDS && IS(a->w[count - 1], "HOLD");
    if (held)
        count--;
    bool timed = count > BOOTH_CHANNELS && count <= BOOTH_MAX_WORDS && is_exposure_word(a->w[count - 1]);
    if (timed)
        count--;
    if (!levels_arg(a, 0, count, duty) || (timed && !exposure_arg(a->w[count], &code)) || !editable(b))
        return false;
    if (b->steps >= BOOTH_MAX_STEPS)
        return REFUSE(E_FULL, "pattern table full");
    memcpy(b->table[b->steps], duty, sizeof duty);
    b->exposure[b->steps] = code;
    set_held(b, b->steps, held);
    b->steps++;
    PUT(o, " ");
    put_u32(o, (uint32_t)(b->steps - 1));
    put_step_pulses(b, o, duty, code);
    return true;
}

static bool cmd_pset(booth_t *b, const words_t *a, out_t *o, uint32_t now_us)
{
    uint16_t duty[BOOTH_CHANNELS];
    uint16_t n = a->n, code = 0;
    uint32_t index;
    bool now = n > BOOTH_CHANNELS + 1 && n <= BOOTH_MAX_WORDS && IS(a->w[n - 1], "NOW");
    if (now)
        n--;
    bool timed = n > BOOTH_CHANNELS + 1 && n <= BOOTH_MAX_WORDS && is_exposure_word(a->w[n - 1]);
    if (timed)
        n--;
    if (n != BOOTH_CHANNELS + 1 || !decimal(a->w[0], 5, &index))
        return REFUSE(E_ARG, "PSET <step> and " BOOTH_CHANNELS_TEXT " levels [EXP=<us>] [NOW]");
    if (!levels_arg(a, 1, (uint16_t)(n - 1), duty) || (timed && !exposure_arg(a->w[n], &code)))
        return false;
    if (index >= b->steps)
        return REFUSE(E_RANGE, "no such step");
    bool running = b->state == STATE_RUNNING;
    if (running && ((int32_t)index < b->step || ((int32_t)index == b->step && !b->holding)))
        return REFUSE(E_STATE, "step already exposed");
    memcpy(b->table[index], duty, sizeof duty);
    b->exposure[index] = code;
    set_held(b, (uint16_t)index, false);
    put_step_pulses(b, o, duty, code);
    if (running && b->holding && (int32_t)index == b->step) {
        release_hold(b, now_us);
    } else if (now && running && b->mode == MODE_BOOTH && (int32_t)index == b->step + 1 &&
               b->action == ACTION_APPLY) {
        /* The previous step was pulsed and the host has its frame: start this one now. */
        apply_step(b, (uint16_t)index);
        release_hold(b, now_us);
    }
    return true;
}

static bool cmd_arm(booth_t *b, const words_t *a, out_t *o)
{
    booth_mode_t mode = MODE_NONE;
    uint32_t t[3];
    (void)o;
    if (a->n == 4) {
        if (IS(a->w[0], "HOST"))
            mode = MODE_HOST;
        else if (IS(a->w[0], "BOOTH"))
            mode = MODE_BOOTH;
        else if (IS(a->w[0], "CAMERA"))
            mode = MODE_CAMERA;
    }
    if (mode == MODE_NONE)
        return REFUSE(E_ARG, "ARM HOST|BOOTH|CAMERA settle_us pulse_us period_us");
    for (uint8_t i = 0; i < 3; i++)
        if (!decimal(a->w[i + 1], 8, &t[i]))
            return REFUSE(E_ARG, "times are decimal microseconds");
    if (b->state == STATE_RUNNING)
        return REFUSE(E_STATE, "sequence running");
    if (mode != MODE_HOST && b->steps == 0)
        return REFUSE(E_STATE, "pattern table empty");
    if (mode == MODE_BOOTH && (t[2] == 0 || t[2] < t[0] + t[1]))
        return REFUSE(E_RANGE, "period shorter than settle plus pulse");
    b->mode = mode;
    b->settle_us = t[0];
    b->pulse_us = t[1];
    b->period_us = t[2];
    b->state = STATE_ARMED;
    b->step = -1;
    b->triggers = 0;
    b->holding = false;
    return true;
}

static bool cmd_start(booth_t *b, const words_t *a, out_t *o, uint32_t now_us)
{
    (void)o;
    if (!no_args(a))
        return false;
    if (b->state != STATE_ARMED)
        return REFUSE(E_STATE, "not armed");
    b->state = STATE_RUNNING;
    if (b->mode == MODE_CAMERA) {
        apply_step(b, 0);
    } else if (b->mode == MODE_BOOTH) {
        b->t0_us = now_us;
        b->action = ACTION_APPLY;
        b->action_due_us = now_us;
    }
    return true;
}

/* NEXT: returns 1 to reply at once, 2 to defer the reply by settle_us, 0 if refused. */
static uint8_t cmd_next(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return 0;
    if (b->state != STATE_RUNNING || b->mode != MODE_HOST) {
        REFUSE(E_STATE, "not running in HOST mode");
        return 0;
    }
    if (b->steps == 0 || (uint16_t)(b->step + 1) >= b->steps) {
        finish(b);
        PUT(o, " DONE");
        return 1;
    }
    if (is_held(b, (uint16_t)(b->step + 1))) {
        REFUSE(E_STATE, "next step held; expected PSET first");
        return 0;
    }
    apply_step(b, (uint16_t)(b->step + 1));
    b->deferred_due_us = board_micros() + b->settle_us; /* from the LED change, not the reply's framing */
    b->triggers++;
    PUT(o, " ");
    put_i32(o, b->step);
    return 2;
}

static bool cmd_cnt(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return false;
    PUT(o, " ");
    put_u32(o, b->triggers);
    return true;
}

static bool cmd_stat(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return false;
    PUT(o, " STATE=");
    put_text(o, state_names[b->state]);
    PUT(o, " MODE=");
    put_text(o, mode_names[b->mode]);
    PUT(o, " STEP=");
    put_i32(o, b->step);
    PUT(o, " STEPS=");
    put_u32(o, b->steps);
    PUT(o, " TRIG=");
    put_u32(o, b->triggers);
    PUT(o, " WDOG=");
    put_u32(o, b->watchdog_ms);
    PUT(o, " ERR=");
    put_text(o, b->last_error ? b->last_error : BOOTH_TEXT("-"));
    PUT(o, " BAD=");
    put_u32(o, b->bad_frames);
    PUT(o, " LEVELS=");
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        if (c)
            PUT(o, ",");
        /* the wire's 16 bits: duty scaled back from BITS, as the emulator reports it */
        put_hex(o, (uint32_t)b->duty[c] * 0xFFFFul / LEVEL_TOP, 4);
    }
    return true;
}

static bool cmd_wdog(booth_t *b, const words_t *a, out_t *o)
{
    uint32_t ms;
    if (a->n != 1 || !decimal(a->w[0], 7, &ms))
        return REFUSE(E_ARG, "WDOG <milliseconds>");
    if (!(ms == 0 || (ms >= WATCHDOG_MIN_MS && ms <= WATCHDOG_MAX_MS)))
        return REFUSE(E_RANGE, "0 or 50..600000 ms");
    b->watchdog_ms = ms;
    PUT(o, " ");
    put_u32(o, ms);
    return true;
}

static bool cmd_roll(booth_t *b, const words_t *a, out_t *o)
{
    uint32_t us;
    if (a->n != 1 || !decimal(a->w[0], 8, &us))
        return REFUSE(E_ARG, "ROLL <microseconds>");
    if (b->state == STATE_RUNNING)
        return REFUSE(E_STATE, "sequence running");
    b->roll_us = us;
    PUT(o, " ");
    put_u32(o, us);
    return true;
}

static bool cmd_ping(booth_t *b, const words_t *a, out_t *o)
{
    (void)b;
    (void)o;
    return no_args(a);
}

/* ---- the serial in EEPROM (SERIAL, SERIAL= in ID) -------------------------------------- */

/* 1..BOOTH_SERIAL_MAX of A-Z a-z 0-9 . _ - and not "-" alone (the emulator's serial_allowed). */
static bool serial_text_ok(const char *s)
{
    uint8_t n = 0;
    for (; s[n]; n++) {
        char c = s[n];
        bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '.' ||
                  c == '_' || c == '-';
        if (!ok || n >= BOOTH_SERIAL_MAX)
            return false;
    }
    return n > 0 && !(s[0] == '-' && s[1] == '\0');
}

static bool cmd_serial(booth_t *b, const words_t *a, out_t *o)
{
    if (a->n == 0) {
        PUT(o, " ");
        put_serial(o, b);
        return true;
    }
    if (a->n != 1 || !serial_text_ok(a->w[0]))
        return REFUSE(E_ARG, "SERIAL [1..32 of A-Z a-z 0-9 . _ -]");
    if (b->state == STATE_ARMED || b->state == STATE_RUNNING)
        return REFUSE(E_STATE, "sequence armed or running");
    uint8_t len = (uint8_t)strlen(a->w[0]);
    memcpy(b->serial, a->w[0], len);
    b->serial[len] = '\0';
    board_serial_store(b->serial, len);
    PUT(o, " ");
    put_serial(o, b);
    return true;
}

/* ---- frames in ------------------------------------------------------------------------ */

#define REJECT(b, code, literal) reject((b), (code), BOOTH_TEXT(literal))
static void reject(booth_t *b, booth_text_t code, booth_text_t text)
{
    out_t o = {.len = 0};
    b->bad_frames++;
    b->last_error = code;
    PUT(&o, "ERR - ");
    put_text(&o, code);
    PUT(&o, " ");
    put_text(&o, text);
    send_frame('=', 0, &o);
}

/* The command name echoed in replies: at most this many bytes of it (an unknown command
 * could be 1 KiB long; the emulator echoes it whole). */
#define NAME_ECHO_MAX 32u

static void dispatch(booth_t *b, uint8_t seq, const char *name, const words_t *args, uint32_t now_us)
{
    out_t o = {.len = 0};
    uint8_t ok = 0;
    refused = NULL;
    PUT(&o, "OK ");
    put_n(&o, name, NAME_ECHO_MAX);
    if (IS(name, "ID")) ok = cmd_id(b, args, &o);
    else if (IS(name, "SET")) ok = cmd_set(b, args, &o);
    else if (IS(name, "OFF")) ok = cmd_off(b, args, &o);
    else if (IS(name, "PCLR")) ok = cmd_pclr(b, args, &o);
    else if (IS(name, "PADD")) ok = cmd_padd(b, args, &o);
    else if (IS(name, "PSET")) ok = cmd_pset(b, args, &o, now_us);
    else if (IS(name, "ARM")) ok = cmd_arm(b, args, &o);
    else if (IS(name, "START")) ok = cmd_start(b, args, &o, now_us);
    else if (IS(name, "NEXT")) ok = cmd_next(b, args, &o);
    else if (IS(name, "CNT")) ok = cmd_cnt(b, args, &o);
    else if (IS(name, "STAT")) ok = cmd_stat(b, args, &o);
    else if (IS(name, "WDOG")) ok = cmd_wdog(b, args, &o);
    else if (IS(name, "PING")) ok = cmd_ping(b, args, &o);
    else if (IS(name, "SERIAL")) ok = cmd_serial(b, args, &o);
    else if (IS(name, "ROLL")) ok = cmd_roll(b, args, &o);
    else REFUSE(E_CMD, "unknown command");

    if (refused) {
        b->last_error = refused->code;
        o.len = 0;
        PUT(&o, "ERR ");
        put_n(&o, name, NAME_ECHO_MAX);
        PUT(&o, " ");
        put_text(&o, refused->code);
        PUT(&o, " ");
        put_text(&o, refused->text);
        send_frame('=', seq, &o);
    } else if (ok == 2) { /* NEXT: reply once the LEDs have settled */
        char frame[BOOTH_TIMED_MAX];
        if (o.len > sizeof frame - 14)
            o.len = (uint16_t)(sizeof frame - 14);
        board_write_at(frame, (uint8_t)frame_into(frame, '=', seq, &o), b->deferred_due_us);
    } else {
        send_frame('=', seq, &o);
    }
}

/* Walk the line as BoothEmulator._handle_line does: the same checks in the same order. */
static void handle_line(booth_t *b, char *line, uint16_t len, uint32_t now_us)
{
    if (len < 13) {
        REJECT(b, E_FRAME, "frame too short");
        return;
    }
    uint16_t star = (uint16_t)(len - 5);
    if (line[star] != '*') {
        REJECT(b, E_FRAME, "no checksum field");
        return;
    }
    if (!is_hex_text(line + star + 1, 4)) {
        REJECT(b, E_FRAME, "checksum not hex");
        return;
    }
    if (booth_crc16((const uint8_t *)line, star) != (uint16_t)hex_value(line + star + 1, 4)) {
        REJECT(b, E_CRC, "checksum mismatch");
        return;
    }
    if (line[0] != '?' || line[3] != ':' || line[7] != ':') {
        REJECT(b, E_FRAME, "bad header");
        return;
    }
    if (!is_hex_text(line + 1, 2) || !is_hex_text(line + 4, 3)) {
        REJECT(b, E_FRAME, "header not hex");
        return;
    }
    char *body = line + 8;
    uint16_t body_len = (uint16_t)(star - 8);
    if (hex_value(line + 4, 3) != body_len || body_len > BOOTH_MAX_BODY) {
        REJECT(b, E_LEN, "length mismatch");
        return;
    }
    for (uint16_t i = 0; i < body_len; i++) {
        if ((uint8_t)body[i] < 0x20 || (uint8_t)body[i] > 0x7E || body[i] == '*') {
            REJECT(b, E_FRAME, "body not printable");
            return;
        }
    }
    uint8_t seq = (uint8_t)hex_value(line + 1, 2);
    if (seq == 0) {
        REJECT(b, E_FRAME, "sequence 00 is reserved");
        return;
    }
    /* A readable request: feed the watchdog. */
    b->last_host_us = now_us;
    b->watchdog_tripped = false;

    /* Split on single spaces, keeping empty words (as Python's str.split(" ")). */
    body[body_len] = '\0';
    words_t args = {.n = 0};
    const char *name = body;
    for (uint16_t i = 0; i < body_len; i++) {
        if (body[i] == ' ') {
            body[i] = '\0';
            if (args.n < BOOTH_MAX_WORDS)
                args.w[args.n] = body + i + 1;
            args.n++;
        }
    }
    if (args.n > BOOTH_MAX_WORDS)
        args.n = BOOTH_MAX_WORDS + 1; /* too many for any command: E_ARG, never read past w[] */
    dispatch(b, seq, name, &args, now_us);
}

void booth_feed(booth_t *b, uint8_t byte, uint32_t now_us)
{
    if (byte == '\n') {
        if (b->discarding) {
            b->discarding = false;
        } else {
            handle_line(b, b->line, b->line_len, now_us);
        }
        b->line_len = 0;
        booth_poll(b, now_us);
        return;
    }
    if (b->discarding)
        return;
    if (b->line_len >= BOOTH_MAX_LINE) {
        /* Too long to be a frame: throw it away up to its end and say so once. */
        b->line_len = 0;
        b->discarding = true;
        REJECT(b, E_LEN, "line too long");
        return;
    }
    b->line[b->line_len++] = (char)byte;
}

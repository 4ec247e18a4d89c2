/* The booth protocol and sequencer, written from docs/booth-protocol.md and kept to the
 * behaviour of the Python emulator (led_controller/emulator.py), which is the reference:
 * same checks in the same order, same error texts. Plain C99, no AVR headers. */
#include "booth_core.h"

#include <string.h>

#define LEVEL_TOP ((uint16_t)((1ul << BOOTH_LEVEL_BITS) - 1u))
#define WATCHDOG_MIN_MS 50u
#define WATCHDOG_MAX_MS 600000ul

/* ---- CRC-16/CCITT-FALSE, bitwise (small; a 512-byte table buys nothing at 115200 baud) -- */

uint16_t booth_crc16(const uint8_t *data, uint16_t len)
{
    uint16_t crc = 0xFFFF;
    while (len--) {
        crc ^= (uint16_t)(*data++) << 8;
        for (uint8_t bit = 0; bit < 8; bit++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

/* ---- output: frames built in one buffer ------------------------------------------------ */

typedef struct {
    char buf[BOOTH_OUT_MAX];
    uint16_t len;
} out_t;

static void put_str(out_t *o, const char *s)
{
    while (*s && o->len < BOOTH_OUT_MAX - 8)
        o->buf[o->len++] = *s++;
}

static void put_n(out_t *o, const char *s, uint16_t n)
{
    while (n-- && *s && o->len < BOOTH_OUT_MAX - 8)
        o->buf[o->len++] = *s++;
}

static void put_hex(out_t *o, uint32_t v, uint8_t digits)
{
    static const char hex[] = "0123456789ABCDEF";
    while (digits--)
        o->buf[o->len++] = hex[(v >> (4 * digits)) & 0xF];
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

/* Frame `body` (already in body->buf) with mark and seq and send it. */
static void send_frame(char mark, uint8_t seq, const out_t *body)
{
    static out_t frame;
    frame.len = 0;
    frame.buf[frame.len++] = mark;
    put_hex(&frame, seq, 2);
    frame.buf[frame.len++] = ':';
    put_hex(&frame, body->len, 3);
    frame.buf[frame.len++] = ':';
    memcpy(frame.buf + frame.len, body->buf, body->len);
    frame.len += body->len;
    uint16_t crc = booth_crc16((const uint8_t *)frame.buf, frame.len);
    frame.buf[frame.len++] = '*';
    put_hex(&frame, crc, 4);
    frame.buf[frame.len++] = '\n';
    board_write(frame.buf, frame.len);
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

/* ---- sequencing (as BoothEmulator._apply_step, _release_hold, _finish, _all_off) -------- */

static void trigger_low(booth_t *b)
{
    if (b->pulse_high) {
        b->pulse_high = false;
        board_trigger_out(false);
    }
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
    drive(b);
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
    drive(b);
    if (b->mode == MODE_BOOTH) {
        /* The step's slot starts now; later steps keep the period from here. */
        uint32_t applied = board_micros();
        b->t0_us = applied - (uint32_t)b->step * b->period_us;
        b->action = ACTION_PULSE;
        b->action_due_us = applied + b->settle_us;
    }
}

static void finish(booth_t *b)
{
    out_t o = {.len = 0};
    leds_off(b);
    b->state = STATE_DONE;
    b->holding = false;
    b->action = ACTION_NONE;
    put_str(&o, "DONE ");
    put_u32(&o, b->triggers);
    send_event(b, &o);
}

static void run_action(booth_t *b, uint32_t now_us)
{
    if (b->action == ACTION_APPLY) {
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
    } else {
        out_t o = {.len = 0};
        b->triggers++;
        /* The pulse first, then its report: the report must not delay the pulse. */
        board_trigger_out(true);
        b->pulse_high = true;
        b->pulse_end_us = now_us + b->pulse_us;
        put_str(&o, "TRIG ");
        put_u32(&o, b->triggers);
        put_str(&o, " ");
        put_i32(&o, b->step);
        send_event(b, &o);
        b->action = ACTION_APPLY;
        b->action_due_us = b->t0_us + (uint32_t)(b->step + 1) * b->period_us;
    }
}

void booth_exposure(booth_t *b, bool active, uint32_t now_us)
{
    (void)now_us;
    if (b->state != STATE_RUNNING || b->mode != MODE_CAMERA)
        return;
    if (active) {
        out_t o = {.len = 0};
        b->triggers++;
        put_str(&o, "TRIG ");
        put_u32(&o, b->triggers);
        put_str(&o, " ");
        if (b->holding)
            put_str(&o, "HOLD"); /* never the step's index: its levels were not shown */
        else
            put_i32(&o, b->step);
        send_event(b, &o);
    } else if ((uint16_t)(b->step + 1) >= b->steps) {
        finish(b);
    } else {
        apply_step(b, (uint16_t)(b->step + 1));
    }
}

void booth_poll(booth_t *b, uint32_t now_us)
{
    if (b->pulse_high && due(now_us, b->pulse_end_us))
        trigger_low(b);
    if (b->deferred && due(now_us, b->deferred_due_us)) {
        out_t o = {.len = 0};
        b->deferred = false;
        put_str(&o, b->deferred_body);
        send_frame('=', b->deferred_seq, &o);
    }
    while (b->action != ACTION_NONE && due(now_us, b->action_due_us))
        run_action(b, now_us);
    if (b->watchdog_ms && !b->watchdog_tripped &&
        now_us - b->last_host_us >= b->watchdog_ms * 1000ul) {
        b->watchdog_tripped = true;
        if (any_on(b) || b->state == STATE_ARMED || b->state == STATE_RUNNING) {
            out_t o = {.len = 0};
            booth_all_off(b);
            put_str(&o, "WDOG");
            send_event(b, &o);
        }
    }
}

/* ---- boot banner ----------------------------------------------------------------------- */

/* A line end first: whatever the reset left on the line (a half frame, bootloader noise) is then
 * a line of its own, and the banner a clean frame. */
static void booth_banner(booth_t *b)
{
    out_t o = {.len = 0};
    board_write("\n", 1);
    put_str(&o, "BOOT FW=" BOOTH_FIRMWARE " PROTO=1");
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

typedef struct {
    const char *code;
    const char *text;
} refusal_t;

static const refusal_t *refused; /* set by a command that refuses */
static refusal_t refusal_buf;

static bool refuse(const char *code, const char *text)
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
    return a->n == 0 ? true : refuse("E_ARG", "takes no arguments");
}

/* Levels: exactly BOOTH_CHANNELS words of 4 upper-case hex digits, from a->w[first]. */
static bool levels_arg(const words_t *a, uint16_t first, uint16_t count, uint16_t out[BOOTH_CHANNELS])
{
    if (count != BOOTH_CHANNELS)
        return refuse("E_ARG", "needs " BOOTH_CHANNELS_TEXT " levels");
    for (uint16_t i = 0; i < count; i++)
        if (strlen(a->w[first + i]) != 4 || !is_hex_text(a->w[first + i], 4))
            return refuse("E_ARG", "levels are 4 hex digits");
    for (uint16_t i = 0; i < count; i++) /* keep the top BITS bits, as the PWM does */
        out[i] = (uint16_t)(hex_value(a->w[first + i], 4) >> (16 - BOOTH_LEVEL_BITS));
    return true;
}

static bool editable(const booth_t *b)
{
    return (b->state == STATE_ARMED || b->state == STATE_RUNNING) ? refuse("E_STATE", "table in use") : true;
}

static const char *state_name(booth_state_t s)
{
    static const char *const names[] = {"IDLE", "ARMED", "RUNNING", "DONE"};
    return names[s];
}

static const char *mode_name(booth_mode_t m)
{
    static const char *const names[] = {"-", "HOST", "BOOTH", "CAMERA"};
    return names[m];
}

static bool cmd_id(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return false;
    put_str(o, " FW=" BOOTH_FIRMWARE " PROTO=1 CH=" BOOTH_CHANNELS_TEXT " NAMES=" BOOTH_NAMES
               " PEAKS=" BOOTH_PEAKS " BITS=");
    put_u32(o, BOOTH_LEVEL_BITS);
    put_str(o, " STEPS=");
    put_u32(o, BOOTH_MAX_STEPS);
    put_str(o, " SERIAL=");
    put_str(o, b->serial[0] ? b->serial : "-");
    return true;
}

static bool cmd_set(booth_t *b, const words_t *a, out_t *o)
{
    uint16_t duty[BOOTH_CHANNELS];
    (void)o;
    if (!levels_arg(a, 0, a->n, duty))
        return false;
    if (b->state == STATE_RUNNING && (b->mode == MODE_BOOTH || b->mode == MODE_CAMERA))
        return refuse("E_STATE", "sequence running");
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

static bool cmd_padd(booth_t *b, const words_t *a, out_t *o)
{
    uint16_t duty[BOOTH_CHANNELS];
    bool held = a->n == BOOTH_CHANNELS + 1 && strcmp(a->w[a->n - 1], "HOLD") == 0;
    uint16_t count = (uint16_t)(held ? a->n - 1 : a->n);
    if (!levels_arg(a, 0, count, duty) || !editable(b))
        return false;
    if (b->steps >= BOOTH_MAX_STEPS)
        return refuse("E_FULL", "pattern table full");
    memcpy(b->table[b->steps], duty, sizeof duty);
    set_held(b, b->steps, held);
    b->steps++;
    put_str(o, " ");
    put_u32(o, (uint32_t)(b->steps - 1));
    return true;
}

static bool cmd_pset(booth_t *b, const words_t *a, out_t *o, uint32_t now_us)
{
    uint16_t duty[BOOTH_CHANNELS];
    uint16_t n = a->n;
    uint32_t index;
    bool now = n == BOOTH_CHANNELS + 2 && strcmp(a->w[n - 1], "NOW") == 0;
    (void)o;
    if (now)
        n--;
    if (n != BOOTH_CHANNELS + 1 || !decimal(a->w[0], 5, &index))
        return refuse("E_ARG", "PSET <step> and " BOOTH_CHANNELS_TEXT " levels [NOW]");
    if (!levels_arg(a, 1, (uint16_t)(n - 1), duty))
        return false;
    if (index >= b->steps)
        return refuse("E_RANGE", "no such step");
    bool running = b->state == STATE_RUNNING;
    if (running && ((int32_t)index < b->step || ((int32_t)index == b->step && !b->holding)))
        return refuse("E_STATE", "step already exposed");
    memcpy(b->table[index], duty, sizeof duty);
    set_held(b, (uint16_t)index, false);
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
        if (strcmp(a->w[0], "HOST") == 0)
            mode = MODE_HOST;
        else if (strcmp(a->w[0], "BOOTH") == 0)
            mode = MODE_BOOTH;
        else if (strcmp(a->w[0], "CAMERA") == 0)
            mode = MODE_CAMERA;
    }
    if (mode == MODE_NONE)
        return refuse("E_ARG", "ARM HOST|BOOTH|CAMERA settle_us pulse_us period_us");
    for (uint8_t i = 0; i < 3; i++)
        if (!decimal(a->w[i + 1], 8, &t[i]))
            return refuse("E_ARG", "times are decimal microseconds");
    if (b->state == STATE_RUNNING)
        return refuse("E_STATE", "sequence running");
    if (mode != MODE_HOST && b->steps == 0)
        return refuse("E_STATE", "pattern table empty");
    if (mode == MODE_BOOTH && (t[2] == 0 || t[2] < t[0] + t[1]))
        return refuse("E_RANGE", "period shorter than settle plus pulse");
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
        return refuse("E_STATE", "not armed");
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
        refuse("E_STATE", "not running in HOST mode");
        return 0;
    }
    if (b->steps == 0 || (uint16_t)(b->step + 1) >= b->steps) {
        finish(b);
        put_str(o, " DONE");
        return 1;
    }
    if (is_held(b, (uint16_t)(b->step + 1))) {
        refuse("E_STATE", "next step held; expected PSET first");
        return 0;
    }
    apply_step(b, (uint16_t)(b->step + 1));
    b->triggers++;
    put_str(o, " ");
    put_i32(o, b->step);
    return 2;
}

static bool cmd_cnt(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return false;
    put_str(o, " ");
    put_u32(o, b->triggers);
    return true;
}

static bool cmd_stat(booth_t *b, const words_t *a, out_t *o)
{
    if (!no_args(a))
        return false;
    put_str(o, " STATE=");
    put_str(o, state_name(b->state));
    put_str(o, " MODE=");
    put_str(o, mode_name(b->mode));
    put_str(o, " STEP=");
    put_i32(o, b->step);
    put_str(o, " STEPS=");
    put_u32(o, b->steps);
    put_str(o, " TRIG=");
    put_u32(o, b->triggers);
    put_str(o, " WDOG=");
    put_u32(o, b->watchdog_ms);
    put_str(o, " ERR=");
    put_str(o, b->last_error ? b->last_error : "-");
    put_str(o, " BAD=");
    put_u32(o, b->bad_frames);
    put_str(o, " LEVELS=");
    for (uint8_t c = 0; c < BOOTH_CHANNELS; c++) {
        if (c)
            put_str(o, ",");
        /* the wire's 16 bits: duty scaled back from BITS, as the emulator reports it */
        put_hex(o, (uint32_t)b->duty[c] * 0xFFFFul / LEVEL_TOP, 4);
    }
    return true;
}

static bool cmd_wdog(booth_t *b, const words_t *a, out_t *o)
{
    uint32_t ms;
    if (a->n != 1 || !decimal(a->w[0], 7, &ms))
        return refuse("E_ARG", "WDOG <milliseconds>");
    if (!(ms == 0 || (ms >= WATCHDOG_MIN_MS && ms <= WATCHDOG_MAX_MS)))
        return refuse("E_RANGE", "0 or 50..600000 ms");
    b->watchdog_ms = ms;
    put_str(o, " ");
    put_u32(o, ms);
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
    return n > 0 && strcmp(s, "-") != 0;
}

static void put_serial(out_t *o, const booth_t *b)
{
    put_str(o, b->serial[0] ? b->serial : "-");
}

static bool cmd_serial(booth_t *b, const words_t *a, out_t *o)
{
    if (a->n == 0) {
        put_str(o, " ");
        put_serial(o, b);
        return true;
    }
    if (a->n != 1 || !serial_text_ok(a->w[0]))
        return refuse("E_ARG", "SERIAL [1..32 of A-Z a-z 0-9 . _ -]");
    if (b->state == STATE_ARMED || b->state == STATE_RUNNING)
        return refuse("E_STATE", "sequence armed or running");
    uint8_t len = (uint8_t)strlen(a->w[0]);
    memcpy(b->serial, a->w[0], len);
    b->serial[len] = '\0';
    board_serial_store(b->serial, len);
    put_str(o, " ");
    put_serial(o, b);
    return true;
}

/* ---- frames in ------------------------------------------------------------------------ */

static void reject(booth_t *b, const char *code, const char *text)
{
    out_t o = {.len = 0};
    b->bad_frames++;
    b->last_error = code;
    put_str(&o, "ERR - ");
    put_str(&o, code);
    put_str(&o, " ");
    put_str(&o, text);
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
    put_str(&o, "OK ");
    put_n(&o, name, NAME_ECHO_MAX);
    if (strcmp(name, "ID") == 0) ok = cmd_id(b, args, &o);
    else if (strcmp(name, "SET") == 0) ok = cmd_set(b, args, &o);
    else if (strcmp(name, "OFF") == 0) ok = cmd_off(b, args, &o);
    else if (strcmp(name, "PCLR") == 0) ok = cmd_pclr(b, args, &o);
    else if (strcmp(name, "PADD") == 0) ok = cmd_padd(b, args, &o);
    else if (strcmp(name, "PSET") == 0) ok = cmd_pset(b, args, &o, now_us);
    else if (strcmp(name, "ARM") == 0) ok = cmd_arm(b, args, &o);
    else if (strcmp(name, "START") == 0) ok = cmd_start(b, args, &o, now_us);
    else if (strcmp(name, "NEXT") == 0) ok = cmd_next(b, args, &o);
    else if (strcmp(name, "CNT") == 0) ok = cmd_cnt(b, args, &o);
    else if (strcmp(name, "STAT") == 0) ok = cmd_stat(b, args, &o);
    else if (strcmp(name, "WDOG") == 0) ok = cmd_wdog(b, args, &o);
    else if (strcmp(name, "PING") == 0) ok = cmd_ping(b, args, &o);
    else if (strcmp(name, "SERIAL") == 0) ok = cmd_serial(b, args, &o);
    else refuse("E_CMD", "unknown command");

    if (refused) {
        b->last_error = refused->code;
        o.len = 0;
        put_str(&o, "ERR ");
        put_n(&o, name, NAME_ECHO_MAX);
        put_str(&o, " ");
        put_str(&o, refused->code);
        put_str(&o, " ");
        put_str(&o, refused->text);
        send_frame('=', seq, &o);
    } else if (ok == 2) { /* NEXT: reply once the LEDs have settled */
        uint16_t n = o.len < sizeof b->deferred_body - 1 ? o.len : (uint16_t)(sizeof b->deferred_body - 1);
        memcpy(b->deferred_body, o.buf, n);
        b->deferred_body[n] = '\0';
        b->deferred_seq = seq;
        b->deferred_due_us = board_micros() + b->settle_us;
        b->deferred = true;
    } else {
        send_frame('=', seq, &o);
    }
}

/* Walk the line as BoothEmulator._handle_line does: the same checks in the same order. */
static void handle_line(booth_t *b, char *line, uint16_t len, uint32_t now_us)
{
    if (len < 13) {
        reject(b, "E_FRAME", "frame too short");
        return;
    }
    uint16_t star = (uint16_t)(len - 5);
    if (line[star] != '*') {
        reject(b, "E_FRAME", "no checksum field");
        return;
    }
    if (!is_hex_text(line + star + 1, 4)) {
        reject(b, "E_FRAME", "checksum not hex");
        return;
    }
    if (booth_crc16((const uint8_t *)line, star) != (uint16_t)hex_value(line + star + 1, 4)) {
        reject(b, "E_CRC", "checksum mismatch");
        return;
    }
    if (line[0] != '?' || line[3] != ':' || line[7] != ':') {
        reject(b, "E_FRAME", "bad header");
        return;
    }
    if (!is_hex_text(line + 1, 2) || !is_hex_text(line + 4, 3)) {
        reject(b, "E_FRAME", "header not hex");
        return;
    }
    char *body = line + 8;
    uint16_t body_len = (uint16_t)(star - 8);
    if (hex_value(line + 4, 3) != body_len || body_len > BOOTH_MAX_BODY) {
        reject(b, "E_LEN", "length mismatch");
        return;
    }
    for (uint16_t i = 0; i < body_len; i++) {
        if ((uint8_t)body[i] < 0x20 || (uint8_t)body[i] > 0x7E || body[i] == '*') {
            reject(b, "E_FRAME", "body not printable");
            return;
        }
    }
    uint8_t seq = (uint8_t)hex_value(line + 1, 2);
    if (seq == 0) {
        reject(b, "E_FRAME", "sequence 00 is reserved");
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
        reject(b, "E_LEN", "line too long");
        return;
    }
    b->line[b->line_len++] = (char)byte;
}

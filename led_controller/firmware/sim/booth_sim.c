/* booth_sim: runs the booth firmware ELF in simavr (ATmega2560, 16 MHz) with UART0 bridged
 * to a pseudo-terminal, for the tests' far end.
 *
 * The bridge is our own rather than simavr's uart_pty part: uart_pty raises the UART's input
 * IRQ from its own thread while avr_run() runs in this one, which races on simavr's UART state
 * (requests were lost now and then under load). Here one thread does everything: the pty is
 * polled every 100 us of simulated time and bytes are fed to the UART while it signals XON.
 *
 * The LED pins are not simavr's: sim/pin_model.c computes them from the firmware's writes to
 * timers 3, 4, 5 per the ATmega2560 datasheet (simavr 1.6's output-compare pins are wrong for this
 * firmware, and its 16-bit fast PWM runs the simulation at a tenth of real time).
 *
 * stdout, one line each:  "pty <path>" once ready; "pulse <t_us> <since_us> <l0> .. <l6>" on
 * each rising edge of the trigger output (PA0), with the level of every LED channel at that
 * moment (pin_model_level: PWM duty, 0 or 1) and the time since a level last changed, times in
 * us with 3 decimals; "pulse_end <t_us>" on its falling edge; "ok <command> ..." answering a
 * command; with "trace 1", "tx <t_us>" as the firmware starts sending a frame, "tcnt <timer>
 * <t_us>" on each write of TCNT3..5 and "expin <0|1> <t_us>" on each change of ExposureActive.
 * stdin commands: "exp 0|1" drive the ExposureActive input (PD0/INT0) and run 2 ms of
 * simulated time so the firmware has served the edge before "ok exp" (simavr compromise:
 * the emulator's exposure_active is synchronous); "levels" -> "ok levels <t_us> <top> <d0> ..";
 * "quit"; the camera side (section below): "expose <T_us> <rows> <line_us> <latency_us>" and
 * "integrate <start_us> <T_us> <rows> <line_us>" answer "ok expose|integrate <start_us> <c0>
 * .. <c6> (per row)": the cycles each LED pin was high in each row's exposure window.
 *
 * Time is simavr's simulated time; simavr sleeps in real time while the firmware sleeps, so
 * it runs close to real time (never faster while the CPU idles). */
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_time.h"
#include "avr_uart.h"
#include "pin_model.h"
#include <errno.h>
#include <pty.h>
#include <termios.h>

#define CHANNELS 7 /* reported channels: OC3A OC3B OC3C OC4A OC4B OC4C OC5A (the firmware's order) */

static avr_t *avr;
static int pty_master = -1, pty_slave = -1;
static char pty_name[128];
static uint8_t to_avr[4096];   /* host -> firmware, a ring */
static size_t to_head, to_tail;
static uint8_t from_avr[8192]; /* firmware -> host, waiting for the pty */
static size_t from_len;
static int uart_xon = 1;
static avr_irq_t *uart_input;
static avr_irq_t *exposure_irq;
static int trace; /* "trace 1" on stdin: tx, tcnt and expin lines on stdout */

static uint32_t now_us(void) { return (uint32_t)avr_cycles_to_usec(avr, avr->cycle); }

/* Simulated time in us, to the cycle (16 MHz: 1/16 us). */
static double cycle_us(avr_cycle_count_t cycle) { return (double)cycle / (avr->frequency / 1e6); }

static void print_levels(void)
{
    for (int c = 0; c < CHANNELS; c++)
        printf(" %.9g", pin_model_level(c));
    printf("\n");
    fflush(stdout);
}

static void trigger_out_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    pin_model_advance();
    if (value) {
        printf("pulse %.3f %.3f", cycle_us(avr->cycle), cycle_us(avr->cycle - pin_model_changed_at()));
        print_levels();
    } else {
        printf("pulse_end %.3f\n", cycle_us(avr->cycle));
        fflush(stdout);
    }
}

static int run_for_us(uint32_t us)
{
    avr_cycle_count_t until = avr->cycle + avr_usec_to_cycles(avr, us);
    while (avr->cycle < until) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed)
            return state;
        pin_model_advance();
    }
    return cpu_Running;
}

static struct timespec wall_start;

static void pace_sleep(avr_t *a, avr_cycle_count_t how_long)
{
    (void)how_long;
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    int64_t wall_us = (int64_t)(now.tv_sec - wall_start.tv_sec) * 1000000 + (now.tv_nsec - wall_start.tv_nsec) / 1000;
    int64_t sim_us = (int64_t)avr_cycles_to_usec(a, a->cycle);
    if (sim_us > wall_us + 500)
        usleep((useconds_t)(sim_us - wall_us));
}

/* ---- the UART <-> pty bridge (all on the simulation thread) ---- */

static void uart_feed(void)
{
    while (uart_xon && to_tail != to_head) {
        uint8_t byte = to_avr[to_tail];
        to_tail = (to_tail + 1) % sizeof to_avr;
        avr_raise_irq(uart_input, byte); /* may call uart_xoff_hook at once */
    }
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq, (void)value, (void)param;
    uart_xon = 1;
    uart_feed();
}

static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq, (void)value, (void)param;
    uart_xon = 0;
}

static void pty_flush_out(void)
{
    while (from_len) {
        ssize_t n = write(pty_master, from_avr, from_len);
        if (n <= 0)
            return; /* EAGAIN: nobody reads yet; keep the bytes */
        memmove(from_avr, from_avr + n, from_len - (size_t)n);
        from_len -= (size_t)n;
    }
}

static int frame_start = 1; /* the next byte from the firmware starts a frame */

static void uart_output_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq, (void)param;
    if (trace && frame_start)
        printf("tx %.3f\n", cycle_us(avr->cycle));
    frame_start = value == '\n';
    if (from_len == sizeof from_avr)
        pty_flush_out();
    if (from_len < sizeof from_avr)
        from_avr[from_len++] = (uint8_t)value;
}

static void pty_service(void)
{
    size_t room = (to_tail + sizeof to_avr - to_head - 1) % sizeof to_avr;
    if (room) {
        uint8_t chunk[512];
        ssize_t n = read(pty_master, chunk, room < sizeof chunk ? room : sizeof chunk);
        for (ssize_t i = 0; i < n; i++) {
            to_avr[to_head] = chunk[i];
            to_head = (to_head + 1) % sizeof to_avr;
        }
    }
    pty_flush_out();
    uart_feed();
}

static int pty_open(void)
{
    struct termios tio;
    if (openpty(&pty_master, &pty_slave, pty_name, NULL, NULL) < 0)
        return -1;
    /* Raw on both ends before anyone opens the slave: no echo, no line editing. The slave
     * stays open here so the master never sees a hang-up between two hosts. */
    tcgetattr(pty_slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(pty_slave, TCSANOW, &tio);
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    return 0;
}

/* ---- the camera side: exposure windows over the LED pins ----
 *
 * The camera's exposure (and each row's, for a rolling shutter: row r starts r line times
 * after row 0) is a window of simulated time; what a row collects from LED i is the time pin i
 * was high in its window (pin_model_on_cycles), exact to the cycle. ExposureActive (PD0) is
 * driven with the flash window, from the last row's start to the first row's end (the whole
 * exposure for a global shutter): the signal a camera-master booth needs (docs/flash-energy.md).
 *   expose <T_us> <rows> <line_us> <latency_us>: an exposure starting latency_us from now;
 *   integrate <start_us> <T_us> <rows> <line_us>: windows from an absolute start (booth master:
 *     the trigger pulse's time plus the camera's latency).
 * One request at a time; the answer comes once the last row's window is over. */

#define MAX_ROWS 8192

static void (*core_reset)(struct avr_t *a);

static void reset_all(struct avr_t *a)
{
    if (core_reset)
        core_reset(a);
    pin_model_reset();
}

static void set_exposure_input(int high)
{
    avr_raise_irq(exposure_irq, high != 0);
    if (trace)
        printf("expin %d %.3f\n", high != 0, cycle_us(avr->cycle));
}

static avr_cycle_count_t edge_timer(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a, (void)when;
    set_exposure_input(param != NULL);
    return 0;
}

static void tcnt_trace(int timer, avr_cycle_count_t cycle)
{
    if (trace)
        printf("tcnt %d %.3f\n", timer, cycle_us(cycle));
}

static struct {
    int pending;
    const char *kind;
    avr_cycle_count_t start, length, line;
    int rows;
} window;

static avr_cycle_count_t us_cycles(double us) { return (avr_cycle_count_t)(us * (avr->frequency / 1e6) + 0.5); }

/* Returns 1 if `text` is a camera command (answered now if it is malformed, else once served). */
static int camera_command(const char *text)
{
    double a, b, c, d;
    int rows;
    int expose = strncmp(text, "expose ", 7) == 0;
    if (!expose && strncmp(text, "integrate ", 10) != 0)
        return 0;
    if (window.pending) {
        printf("error %s: an exposure is already being served\n", expose ? "expose" : "integrate");
        return 1;
    }
    int n = expose ? sscanf(text + 7, "%lf %d %lf %lf", &a, &rows, &b, &c)
                   : sscanf(text + 10, "%lf %lf %d %lf", &d, &a, &rows, &b);
    if (n != 4 || !(a > 0) || rows < 1 || rows > MAX_ROWS || b < 0 || (expose && c < 0) || (!expose && d < 0)) {
        printf("error %s expects %s\n", expose ? "expose" : "integrate",
               expose ? "<T_us > 0> <rows 1..8192> <line_us >= 0> <latency_us >= 0>"
                      : "<start_us >= 0> <T_us > 0> <rows 1..8192> <line_us >= 0>");
        return 1;
    }
    window.kind = expose ? "expose" : "integrate";
    window.length = us_cycles(a);
    window.rows = rows;
    window.line = us_cycles(b);
    window.start = expose ? avr->cycle + us_cycles(c) : us_cycles(d);
    window.pending = 1;
    if (expose) {
        avr_cycle_count_t skew = (avr_cycle_count_t)(rows - 1) * window.line;
        if (skew >= window.length) {
            printf("error expose: rolling shutter skew %.3f us is not shorter than the exposure %.3f us; "
                   "expected a flash window\n", cycle_us(skew), cycle_us(window.length));
            window.pending = 0;
            return 1;
        }
        avr_cycle_timer_register(avr, window.start + skew - avr->cycle, edge_timer, (void *)1);
        avr_cycle_timer_register(avr, window.start + window.length - avr->cycle, edge_timer, NULL);
    }
    return 1;
}

static void camera_serve(void)
{
    if (!window.pending)
        return;
    avr_cycle_count_t end = window.start + (avr_cycle_count_t)(window.rows - 1) * window.line + window.length;
    if (avr->cycle < end)
        return;
    window.pending = 0;
    printf("ok %s %.4f", window.kind, cycle_us(window.start));
    for (int r = 0; r < window.rows; r++) {
        avr_cycle_count_t from = window.start + (avr_cycle_count_t)r * window.line;
        for (int c = 0; c < CHANNELS; c++)
            printf(" %lld", (long long)pin_model_on_cycles(c, from, from + window.length));
    }
    printf("\n");
    fflush(stdout);
}

static char cmd[256];
static size_t cmd_len;

/* Read what is on stdin; returns -1 on quit or EOF. */
static int serve_stdin(void)
{
    char chunk[256];
    ssize_t n = read(0, chunk, sizeof chunk);
    if (n <= 0)
        return -1;
    for (ssize_t i = 0; i < n; i++) {
        if (chunk[i] != '\n') {
            if (cmd_len < sizeof cmd - 1)
                cmd[cmd_len++] = chunk[i];
            continue;
        }
        cmd[cmd_len] = '\0';
        cmd_len = 0;
        if (strcmp(cmd, "quit") == 0)
            return -1;
        if (strcmp(cmd, "exp 0") == 0 || strcmp(cmd, "exp 1") == 0) {
            set_exposure_input(cmd[4] == '1');
            run_for_us(2000);
            printf("ok exp %c %u\n", cmd[4], now_us());
        } else if (strcmp(cmd, "levels") == 0) {
            pin_model_advance();
            printf("ok levels %.3f", cycle_us(avr->cycle));
            print_levels();
        } else if (strcmp(cmd, "trace 0") == 0 || strcmp(cmd, "trace 1") == 0) {
            trace = cmd[6] == '1';
            printf("ok trace %d\n", trace);
        } else if (camera_command(cmd)) {
            /* answered by the camera side, now or once its exposure is over */
        } else if (strncmp(cmd, "peek ", 5) == 0) {
            /* "peek <addr> <n>": n bytes of data space (SRAM, I/O) in hex, for debugging */
            unsigned addr = 0, count = 0;
            if (sscanf(cmd + 5, "%x %u", &addr, &count) == 2 && addr + count <= avr->ramend + 1u) {
                printf("ok peek %u", now_us());
                for (unsigned i = 0; i < count; i++)
                    printf(" %02X", avr->data[addr + i]);
                printf("\n");
            } else {
                printf("error peek expects <hex address> <count> within RAM\n");
            }
        } else {
            printf("error unknown command %s\n", cmd);
        }
        fflush(stdout);
    }
    return 0;
}

int main(int argc, char **argv)
{
    elf_firmware_t fw;
    if (argc != 2) {
        fprintf(stderr, "usage: booth_sim FIRMWARE.elf\n");
        return 2;
    }
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[1], &fw) != 0) {
        fprintf(stderr, "booth_sim: cannot read %s; expected an AVR ELF file\n", argv[1]);
        return 2;
    }
    avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) {
        fprintf(stderr, "booth_sim: simavr has no atmega2560 core\n");
        return 2;
    }
    avr_init(avr);
    avr->frequency = 16000000;
    avr_load_firmware(avr, &fw);
    avr->frequency = 16000000;
    avr->log = LOG_ERROR;
    pin_model_install(avr);
    pin_model_tcnt_hook = tcnt_trace;
    core_reset = avr->reset; /* a reset (the watchdog's) puts the pins back to inputs */
    avr->reset = reset_all;

    uint32_t flags = 0; /* no stdio dump of the UART: it carries frames */
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    if (pty_open() < 0) {
        fprintf(stderr, "booth_sim: cannot open a pseudo-terminal: %s\n", strerror(errno));
        return 2;
    }
    uart_input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_output_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), uart_xon_hook, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), uart_xoff_hook, NULL);
    exposure_irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 0);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A'), 0), trigger_out_hook, NULL);

    /* Keep simulated time from running ahead of the wall clock (the driver's timeouts are wall
     * time); simavr's own raw sleep callback usleeps for every idle stretch whether or not the
     * simulation is behind. In practice the simulation is behind: simavr steps the PWM timers
     * nearly cycle by cycle (docs/booth-firmware.md, section 5). */
    clock_gettime(CLOCK_MONOTONIC, &wall_start);
    avr->sleep = pace_sleep;

    /* Boot before announcing the port: simavr's UART drops bytes that arrive before the
     * firmware enables its receiver (a real board, too, is deaf while it boots). */
    run_for_us(20000);

    printf("pty %s\n", pty_name);
    fflush(stdout);

    struct pollfd in = {.fd = 0, .events = POLLIN};
    avr_cycle_count_t next_poll = 0;
    for (;;) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "booth_sim: firmware stopped (state %d) at %u us\n", state, now_us());
            break;
        }
        pin_model_advance();
        camera_serve();
        if (avr->cycle >= next_poll) { /* pty and stdin every 100 us of simulated time */
            next_poll = avr->cycle + avr_usec_to_cycles(avr, 100);
            pty_service();
            if (poll(&in, 1, 0) > 0 && serve_stdin() < 0)
                break;
        }
    }
    pty_flush_out();
    close(pty_master);
    close(pty_slave);
    return 0;
}

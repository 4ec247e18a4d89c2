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
 * The board around the firmware resets when the host opens the pty (DTR, led_controller/usb_link.py):
 * the bootloader holds the UART for a wall-clock window, then the firmware runs from its reset vector.
 * Simulated time keeps running forward across resets (every time printed and read is on that clock).
 *
 * stdout, one line each:  "pty <path>" once ready; "pulse <t_us> <since_us> <l0> .. <l6>" on
 * each rising edge of the trigger output (PA0), with the level of every LED channel at that
 * moment (pin_model_level: PWM duty, 0 or 1) and the time since a level last changed, times in
 * us with 3 decimals; "pulse_end <t_us>" on its falling edge; "ok <command> ..." answering a
 * command; with "trace 1", "tx <t_us>" as the firmware starts sending a frame, "tcnt <timer>
 * <t_us>" on each write of TCNT3..5 and "expin <0|1> <t_us>" on each change of ExposureActive.
 * stdin commands: "exp 0|1" drive the ExposureActive input (PD0/INT0) ("exp float": the wire
 * loose, held by the pull-up or floating) and run 2 ms of simulated time so the firmware has
 * served the edge before "ok exp" (simavr compromise: the emulator's exposure_active is
 * synchronous); "levels" -> "ok levels <t_us> <top> <d0> .."; "link" -> "ok link <t_us> opens
 * <n> resets <n> bootloader <0|1>"; "quit"; the camera side (section below): "expose <T_us> <rows>
 * <line_us> <latency_us>" and "integrate <start_us> <T_us> <rows> <line_us>" answer "ok
 * expose|integrate <start_us> <c0> .. <c6> (per row)": the cycles each LED pin was high in each
 * row's exposure window.
 *
 * Time is simavr's simulated time; simavr sleeps in real time while the firmware sleeps, so
 * it runs close to real time (never faster while the CPU idles).
 *
 * The board around the MCU is a stock Arduino Mega's (led_controller/usb_link.py has the same
 * model for the Python emulator): a host opening the pty (inotify IN_OPEN on the slave node, the
 * first open while no host holds it) resets the MCU (avr_reset: pins inputs, LEDs off) and the
 * bootloader owns the UART for --bootloader-ms of wall-clock time, swallowing the host's bytes
 * (each one keeps it 1 s longer); then the firmware runs from its reset vector and sends its boot
 * banner. --no-auto-reset: a board with auto-reset disabled. What the firmware sends while no
 * host has the port open is lost; a host's close drops what it did not read. --latency-us holds
 * short replies until the next tick of a USB-serial chip's latency timer (full 62-byte packets
 * go at once). --eeprom FILE keeps the MCU's EEPROM (the booth's serial) in FILE across runs;
 * resets keep it in any case, as a real EEPROM does.
 *
 * usage: booth_sim [--no-auto-reset] [--bootloader-ms N] [--latency-us N] [--eeprom FILE] FIRMWARE.elf */
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
#include "avr_eeprom.h"
#include "avr_uart.h"
#include "pin_model.h"
#include <errno.h>
#include <pty.h>
#include <sys/inotify.h>
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

/* Simulated time keeps running across resets (avr_reset may restart the cycle counter). */
static avr_cycle_count_t cycle_base;
static avr_cycle_count_t sim_cycles(void) { return cycle_base + avr->cycle; }
static uint32_t now_us(void) { return (uint32_t)avr_cycles_to_usec(avr, sim_cycles()); }

/* Simulated time in us, to the cycle (16 MHz: 1/16 us). */
static double cycle_us(avr_cycle_count_t cycle) { return (double)cycle / (avr->frequency / 1e6); }
/* The host's clock: avr->cycle (the pin model's and the firmware's, restarted by a reset) made
 * monotonic across resets. Every time printed is on it; times read (integrate) are converted back. */
static double ext_us(avr_cycle_count_t cycle) { return cycle_us(cycle_base + cycle); }

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
        printf("pulse %.3f %.3f", ext_us(avr->cycle), cycle_us(avr->cycle - pin_model_changed_at()));
        print_levels();
    } else {
        printf("pulse_end %.3f\n", ext_us(avr->cycle));
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
    int64_t sim_us = (int64_t)avr_cycles_to_usec(a, cycle_base + a->cycle);
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

/* ---- the board's link: reset on open, bootloader, latency timer (usb_link.py's model) ---- */

static int auto_reset = 1;
static uint32_t bootloader_ms = 1600;  /* usb_link.MEGA_BOOTLOADER_S */
static uint32_t byte_hold_ms = 1000;   /* usb_link.BOOTLOADER_BYTE_HOLD_S */
static uint32_t latency_us;            /* 0: replies at once */
static const char *eeprom_file;
static int watch_fd = -1;
static int host_opens;
static int in_bootloader;
static int64_t bootloader_end_us;      /* wall clock, monotonic */
static int64_t latency_due_us;
static uint32_t resets;
#define USB_PACKET_PAYLOAD 62

static int64_t wall_us(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000000 + t.tv_nsec / 1000;
}

static void pty_flush_out(void);

static void eeprom_file_io(int save)
{
    avr_eeprom_desc_t desc = {.ee = NULL, .offset = 0, .size = 4096};
    static uint8_t image[4096];
    if (!eeprom_file)
        return;
    desc.ee = image;
    /* simavr 1.6's EEPROM ioctls do their work but return -1: their result is not checked. */
    if (save) {
        avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &desc);
        FILE *f = fopen(eeprom_file, "wb");
        if (f) {
            fwrite(image, 1, desc.size, f);
            fclose(f);
        }
        return;
    }
    FILE *f = fopen(eeprom_file, "rb");
    if (!f)
        return; /* a new board: blank EEPROM */
    size_t n = fread(image, 1, sizeof image, f);
    fclose(f);
    desc.size = (uint32_t)n;
    if (n)
        avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &desc);
}

/* ---- the ExposureActive wire (PD0): driven by the camera, or loose ---------------------- */

static int exposure_level;   /* what the camera drives (idle low) */
static int exposure_floating; /* "exp float": the wire is loose */
#define PIND_ADDR 0x29
#define PORTD_ADDR 0x2B
#define DDRD_ADDR 0x2A

/* Drive the pin, also when simavr's IRQ already holds that value (after a reset the pin register
 * is cleared but the IRQ keeps its last value: raise the other value first; the firmware's INT0
 * is off until it boots, so this makes no edge it sees). */
static void exposure_drive(int level, int force)
{
    if (force)
        avr_raise_irq(exposure_irq, !level);
    avr_raise_irq(exposure_irq, level);
}

/* A loose wire: the internal pull-up (PORTD0 set, DDRD0 clear) holds it high; without it the
 * input floats and picks up noise, each poll a random level (spurious edges, as on a real board). */
static void exposure_float_step(void)
{
    if (!exposure_floating) {
        /* simavr 1.6 drives an input high when the firmware writes its pull-up bit, whatever drives
         * the pin from outside: the camera's output wins again (before the firmware can use it). */
        if ((avr->data[PIND_ADDR] & 1) != exposure_level)
            avr_raise_irq(exposure_irq, exposure_level);
        return;
    }
    int pulled_up = (avr->data[PORTD_ADDR] & 1) && !(avr->data[DDRD_ADDR] & 1);
    exposure_drive(pulled_up ? 1 : (rand() & 1), 0);
}

/* The host's open asserted DTR: the Mega resets and its bootloader takes the UART. */
static void board_reset(void)
{
    avr_cycle_count_t before = sim_cycles();
    avr_reset(avr);
    if (avr->cycle < before - cycle_base) /* the counter restarted: keep simulated time monotonic */
        cycle_base = before - avr->cycle;
    uart_xon = 1;
    to_head = to_tail = 0;
    if (!exposure_floating)
        exposure_drive(exposure_level, 1); /* the camera still drives the wire */
    in_bootloader = 1;
    bootloader_end_us = wall_us() + (int64_t)bootloader_ms * 1000;
    resets++;
    eeprom_file_io(1);
}

static void port_events(void)
{
    char buf[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
    ssize_t n;
    while ((n = read(watch_fd, buf, sizeof buf)) > 0) {
        for (char *p = buf; p < buf + n;) {
            struct inotify_event *ev = (struct inotify_event *)p;
            p += sizeof *ev + ev->len;
            if (ev->mask & IN_OPEN) {
                if (host_opens++ == 0) {
                    from_len = 0;
                    if (auto_reset)
                        board_reset();
                }
            }
            if ((ev->mask & (IN_CLOSE_WRITE | IN_CLOSE_NOWRITE)) && host_opens > 0 && --host_opens == 0) {
                from_len = 0; /* the kernel frees a closed tty's buffers: unread bytes are gone */
                tcflush(pty_slave, TCIFLUSH);
            }
        }
    }
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
        printf("tx %.3f\n", ext_us(avr->cycle));
    frame_start = value == '\n';
    if (watch_fd >= 0 && host_opens == 0)
        return; /* nobody has the port open: the USB-serial chip drops it */
    if (from_len == 0 && latency_us) {
        int64_t now = wall_us();
        latency_due_us = now + (int64_t)latency_us - now % (int64_t)latency_us; /* the timer's next tick */
    }
    if (from_len == sizeof from_avr)
        pty_flush_out();
    if (from_len < sizeof from_avr)
        from_avr[from_len++] = (uint8_t)value;
}

static void pty_service(void)
{
    size_t room = (to_tail + sizeof to_avr - to_head - 1) % sizeof to_avr;
    if (watch_fd >= 0)
        port_events();
    if (in_bootloader) {
        uint8_t chunk[512];
        ssize_t n = read(pty_master, chunk, sizeof chunk);
        int64_t now = wall_us();
        if (n > 0 && bootloader_end_us < now + (int64_t)byte_hold_ms * 1000)
            bootloader_end_us = now + (int64_t)byte_hold_ms * 1000; /* swallowed; the bootloader stays */
        if (now >= bootloader_end_us)
            in_bootloader = 0; /* the firmware runs from its reset vector */
        return;
    }
    if (room) {
        uint8_t chunk[512];
        ssize_t n = read(pty_master, chunk, room < sizeof chunk ? room : sizeof chunk);
        for (ssize_t i = 0; i < n; i++) {
            to_avr[to_head] = chunk[i];
            to_head = (to_head + 1) % sizeof to_avr;
        }
    }
    if (!latency_us || from_len >= USB_PACKET_PAYLOAD || wall_us() >= latency_due_us)
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

static int edges_pending;
static void edges_register(void);

static void reset_all(struct avr_t *a)
{
    if (core_reset)
        core_reset(a);
    pin_model_reset();
    edges_register(); /* avr_reset dropped every cycle timer: the camera's edges come all the same */
}

static void set_exposure_input(int high)
{
    exposure_floating = 0; /* the camera drives the wire (kept across a reset: board_reset) */
    exposure_level = high != 0;
    avr_raise_irq(exposure_irq, high != 0);
    if (trace)
        printf("expin %d %.3f\n", high != 0, ext_us(avr->cycle));
}

/* The exposure's ExposureActive edges not yet driven: bit 1 the rise, bit 0 the fall; their cycles. */
static avr_cycle_count_t edge_at[2];

static avr_cycle_count_t edge_timer(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a, (void)when;
    set_exposure_input(param != NULL);
    edges_pending &= ~(1 << (param != NULL));
    return 0;
}

static void edges_register(void)
{
    for (int rise = 0; rise < 2; rise++)
        if (edges_pending & (1 << rise))
            avr_cycle_timer_register(avr, edge_at[rise] > avr->cycle ? edge_at[rise] - avr->cycle : 1, edge_timer,
                                     rise ? (void *)1 : NULL);
}

static void tcnt_trace(int timer, avr_cycle_count_t cycle)
{
    if (trace)
        printf("tcnt %d %.3f\n", timer, ext_us(cycle));
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
    if (!expose && us_cycles(d) < cycle_base) {
        printf("error integrate: start %.3f us is before the board's last reset (%.3f us); expected a later window\n",
               d, cycle_us(cycle_base));
        return 1;
    }
    window.start = expose ? avr->cycle + us_cycles(c) : us_cycles(d) - cycle_base;
    window.pending = 1;
    if (expose) {
        avr_cycle_count_t skew = (avr_cycle_count_t)(rows - 1) * window.line;
        if (skew >= window.length) {
            printf("error expose: rolling shutter skew %.3f us is not shorter than the exposure %.3f us; "
                   "expected a flash window\n", cycle_us(skew), cycle_us(window.length));
            window.pending = 0;
            return 1;
        }
        edge_at[1] = window.start + skew;
        edge_at[0] = window.start + window.length;
        edges_pending = 3;
        edges_register();
    }
    return 1;
}

static void camera_serve(void)
{
    if (!window.pending)
        return;
    avr_cycle_count_t end = window.start + (avr_cycle_count_t)(window.rows - 1) * window.line + window.length;
    /* Not before the exposure's falling edge is on the wire: simavr's sleep jump can take the cycle
     * count past a cycle timer before it runs (it runs at the next avr_run), and a next request
     * read in between would re-register the edge timers and cancel it: the next rise would then
     * find the line still high (no edge, no pulses). Answering only once both edges ran closes
     * that window; the firmware has then seen the edge too. */
    if (avr->cycle < end || edges_pending > 0)
        return;
    window.pending = 0;
    printf("ok %s %.4f", window.kind, ext_us(window.start));
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
        if (strcmp(cmd, "exp float") == 0) {
            exposure_floating = 1;
            exposure_float_step();
            if (!in_bootloader)
                run_for_us(2000);
            printf("ok exp float %u\n", now_us());
        } else if (strcmp(cmd, "exp 0") == 0 || strcmp(cmd, "exp 1") == 0) {
            set_exposure_input(cmd[4] == '1');
            if (!in_bootloader) /* in the bootloader the firmware does not run */
                run_for_us(2000);
            printf("ok exp %c %u\n", cmd[4], now_us());
        } else if (strcmp(cmd, "link") == 0) {
            printf("ok link %u opens %d resets %u bootloader %d\n", now_us(), host_opens, resets, in_bootloader);
        } else if (strcmp(cmd, "levels") == 0) {
            pin_model_advance();
            printf("ok levels %.3f", ext_us(avr->cycle));
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
    const char *elf = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--no-auto-reset") == 0)
            auto_reset = 0;
        else if (strcmp(argv[i], "--bootloader-ms") == 0 && i + 1 < argc)
            bootloader_ms = (uint32_t)strtoul(argv[++i], NULL, 10);
        else if (strcmp(argv[i], "--latency-us") == 0 && i + 1 < argc)
            latency_us = (uint32_t)strtoul(argv[++i], NULL, 10);
        else if (strcmp(argv[i], "--eeprom") == 0 && i + 1 < argc)
            eeprom_file = argv[++i];
        else if (argv[i][0] != '-' && !elf)
            elf = argv[i];
        else
            elf = NULL, i = argc; /* unknown option: usage */
    }
    if (!elf) {
        fprintf(stderr, "usage: booth_sim [--no-auto-reset] [--bootloader-ms N] [--latency-us N] "
                        "[--eeprom FILE] FIRMWARE.elf\n");
        return 2;
    }
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "booth_sim: cannot read %s; expected an AVR ELF file\n", elf);
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
    eeprom_file_io(0); /* the board's EEPROM as the last run left it */
    exposure_drive(0, 1); /* the camera's ExposureActive output, idle low */

    /* Boot before announcing the port: simavr's UART drops bytes that arrive before the
     * firmware enables its receiver (a real board, too, is deaf while it boots). */
    run_for_us(20000);

    /* Watch the slave node before its path is handed out: every host open is seen. */
    watch_fd = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    if (watch_fd < 0 || inotify_add_watch(watch_fd, pty_name, IN_OPEN | IN_CLOSE_WRITE | IN_CLOSE_NOWRITE) < 0) {
        fprintf(stderr, "booth_sim: cannot watch %s for opens (%s); expected Linux inotify\n", pty_name,
                strerror(errno));
        return 2;
    }
    printf("pty %s\n", pty_name);
    fflush(stdout);

    struct pollfd in = {.fd = 0, .events = POLLIN};
    avr_cycle_count_t next_poll = 0;
    for (;;) {
        if (in_bootloader) { /* the MCU runs the bootloader, not the firmware: wall-clock time */
            struct pollfd fds[3] = {{.fd = pty_master, .events = POLLIN}, {.fd = watch_fd, .events = POLLIN},
                                    {.fd = 0, .events = POLLIN}};
            poll(fds, 3, 1);
            pty_service();
            if ((fds[2].revents & (POLLIN | POLLHUP)) && serve_stdin() < 0)
                break;
            next_poll = avr->cycle;
            continue;
        }
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "booth_sim: firmware stopped (state %d) at %u us\n", state, now_us());
            break;
        }
        pin_model_advance();
        camera_serve();
        if (avr->cycle >= next_poll) { /* pty and stdin every 100 us of simulated time */
            next_poll = avr->cycle + avr_usec_to_cycles(avr, 100);
            exposure_float_step();
            pty_service();
            if (poll(&in, 1, 0) > 0 && serve_stdin() < 0)
                break;
        }
    }
    pty_flush_out();
    eeprom_file_io(1);
    close(pty_master);
    close(pty_slave);
    return 0;
}

/*
 * Hardware-in-the-loop harness for the turret firmware: runs firmware/build/turret.elf in simavr (an
 * ATmega328P at 16 MHz), drives its pins from a schedule of levels at exact CPU cycles, and copies what
 * its UART sends to a file descriptor (a pseudo-terminal's master side, or a pipe).
 *
 *   turret_hil FIRMWARE.elf SCHEDULE END_CYCLE [--out-fd N] [--byte-log FILE] [--step-log FILE] [--realtime]
 *              [--start-at UNIX_S]
 *
 * SCHEDULE: binary records of 16 bytes, little-endian, in cycle order: uint64 cycle, uint8 pin
 * (0: PB0 = ICP1, the receiver; 1: PD2 = INT0, the zero reference), uint8 level, 6 bytes of padding.
 * Each level is raised on its pin at the first instruction boundary at or after its cycle (the AVR's
 * instructions take 1 to 4 cycles; a Timer1 tick is 8). --byte-log writes one record per UART byte:
 * uint64 cycle at which the firmware wrote it to UDR0, uint8 byte. --step-log writes the uint64 cycle of
 * every level change of the stepper's STEP pin (PB3, OC2A). --realtime runs the emulation up to LEAD_S
 * ahead of the wall clock (a 16 MHz AVR runs faster than real time in simavr otherwise), cycle 0 at
 * --start-at (seconds of the system clock) when given, and writes each UART byte when the wall clock
 * reaches the cycle it was sent at: the link's timing is the chip's, not the emulator's pace (an emulator
 * starved of CPU for less than the lead catches up unseen). SCHEDULE "-" is read from stdin as it comes
 * (records written ahead of the emulation: the virtual turret, beams_sim.virtual_turret), and END_CYCLE 0
 * runs until stdin's end. Without --out-fd the bytes go to stdout; simavr's own messages
 * always go to stderr. A non-blocking --out-fd that is full loses the bytes, as a UART nobody listens
 * to does. The run ends at END_CYCLE; a summary line goes to stderr:
 * "turret_hil: cycles C wall_s W bytes B lost L".
 */
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <avr_ioport.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_cycle_timers.h>
#include <sim_elf.h>
#include <sim_irq.h>

#define CPU_HZ 16000000ULL
#define LEAD_S 0.1
#define GRAIN_S 0.0002 /* the shortest wait for a byte's time: a frame on the wire */
#define PENDING 16384  /* UART bytes emulated and not yet written: 0.3 s of a full link; a power of two */

struct level_change {
    uint64_t cycle;
    uint8_t pin;
    uint8_t level;
};

static struct level_change *schedule;
static size_t schedule_length, schedule_next, schedule_capacity;
static int schedule_fd = -1; /* the schedule read as it comes, or -1 */
static int schedule_ended, inject_armed;
static uint8_t partial_record[16];
static size_t partial_length;
static avr_irq_t *pins[2];
static int out_fd = 1;
static FILE *byte_log;
static FILE *step_log;
static struct {
    uint64_t cycle;
    uint8_t byte;
} pending[PENDING];
static size_t pending_head, pending_tail; /* written up to head, sent by the UART up to tail */
static uint64_t bytes_out, bytes_lost;
static avr_t *avr;

/* Write the bytes the UART sent up to due_cycle. */
static void flush_out(uint64_t due_cycle)
{
    uint8_t chunk[4096];
    size_t length = 0, done = 0;
    while (pending_head != pending_tail && length < sizeof chunk && pending[pending_head % PENDING].cycle <= due_cycle)
        chunk[length++] = pending[pending_head++ % PENDING].byte;
    while (done < length) {
        ssize_t n = write(out_fd, chunk + done, length - done);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            if (errno == EAGAIN) { /* nobody reads the line: the bytes are lost */
                bytes_lost += length - done;
                break;
            }
            perror("turret_hil: write");
            exit(1);
        }
        done += (size_t)n;
    }
    if (length == sizeof chunk)
        flush_out(due_cycle);
}

static void on_uart_byte(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    uint8_t byte = (uint8_t)value;
    if (pending_tail - pending_head == PENDING)
        flush_out(UINT64_MAX); /* no room: the oldest go now */
    pending[pending_tail % PENDING].cycle = avr->cycle;
    pending[pending_tail++ % PENDING].byte = byte;
    bytes_out++;
    if (byte_log) {
        uint64_t cycle = avr->cycle;
        fwrite(&cycle, sizeof cycle, 1, byte_log);
        fwrite(&byte, 1, 1, byte_log);
    }
}

static void on_step_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)param;
    if (irq->value == value)
        return; /* a write that does not change the level */
    uint64_t cycle = avr->cycle;
    fwrite(&cycle, sizeof cycle, 1, step_log);
}

static avr_cycle_count_t inject(struct avr_t *core, avr_cycle_count_t when, void *param)
{
    (void)core;
    (void)param;
    while (schedule_next < schedule_length && schedule[schedule_next].cycle <= when) {
        struct level_change *change = &schedule[schedule_next++];
        avr_raise_irq(pins[change->pin], change->level);
    }
    inject_armed = schedule_next < schedule_length;
    return inject_armed ? schedule[schedule_next].cycle : 0;
}

/* The injection timer, when a level is waiting and none is armed (at once for a level already late). */
static void arm_injection(void)
{
    if (inject_armed || schedule_next == schedule_length)
        return;
    uint64_t at = schedule[schedule_next].cycle;
    avr_cycle_timer_register(avr, at > avr->cycle ? at - avr->cycle : 1, inject, NULL);
    inject_armed = 1;
}

/* Emulated sleep costs no wall time (simavr's default sleeps to its own clock: pace() keeps time). */
static void sleep_none(avr_t *core, avr_cycle_count_t how_long)
{
    (void)core;
    (void)how_long;
}

static double wall_s(void)
{
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (double)now.tv_sec + (double)now.tv_nsec * 1e-9;
}

/* Real time (cycle 0 at `started`, wall_s's clock): write the bytes whose time has come, and wait while
 * the emulation is more than `lead` s ahead, waking for the next byte's time. */
static void pace(double started, double lead)
{
    for (;;) {
        double now = wall_s() - started;
        flush_out(now > 0.0 ? (uint64_t)(now * CPU_HZ) : 0);
        double wait = (double)avr->cycle / CPU_HZ - now - lead;
        if (wait <= 0.0)
            return;
        if (pending_head != pending_tail) {
            double due = (double)pending[pending_head % PENDING].cycle / CPU_HZ - now;
            wait = due < wait ? (due > GRAIN_S ? due : GRAIN_S) : wait;
        }
        usleep((useconds_t)(wait * 1e6));
    }
}

static void add_record(const uint8_t record[16])
{
    if (schedule_length == schedule_capacity) {
        if (schedule_next > schedule_capacity / 2) { /* the injected levels make room */
            memmove(schedule, schedule + schedule_next, (schedule_length - schedule_next) * sizeof *schedule);
            schedule_length -= schedule_next;
            schedule_next = 0;
        } else {
            schedule_capacity = schedule_capacity ? 2 * schedule_capacity : 1024;
            schedule = realloc(schedule, schedule_capacity * sizeof *schedule);
        }
    }
    struct level_change *change = &schedule[schedule_length++];
    memcpy(&change->cycle, record, 8);
    change->pin = record[8];
    change->level = record[9];
    if (change->pin > 1) {
        fprintf(stderr, "turret_hil: schedule record %zu: pin %u is not 0 or 1\n", schedule_length,
                change->pin);
        exit(2);
    }
}

static void load_schedule(const char *path)
{
    FILE *file = fopen(path, "rb");
    if (!file) {
        fprintf(stderr, "turret_hil: cannot open schedule %s: %s\n", path, strerror(errno));
        exit(2);
    }
    uint8_t record[16];
    while (fread(record, sizeof record, 1, file) == 1)
        add_record(record);
    fclose(file);
}

/* What the schedule's stream holds now, without waiting. */
static void read_schedule(void)
{
    uint8_t buffer[4096];
    for (;;) {
        ssize_t n = read(schedule_fd, buffer, sizeof buffer);
        if (n == 0)
            schedule_ended = 1;
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0 && errno != EAGAIN) {
            perror("turret_hil: read schedule");
            exit(1);
        }
        if (n <= 0)
            break;
        for (ssize_t i = 0; i < n; i++) {
            partial_record[partial_length++] = buffer[i];
            if (partial_length == sizeof partial_record) {
                add_record(partial_record);
                partial_length = 0;
            }
        }
    }
    arm_injection();
}

int main(int argc, char *argv[])
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s FIRMWARE.elf SCHEDULE END_CYCLE [--out-fd N] [--byte-log FILE] "
                        "[--step-log FILE] [--realtime] [--start-at UNIX_S]\n", argv[0]);
        return 2;
    }
    uint64_t end_cycle = strtoull(argv[3], NULL, 10);
    int realtime = 0;
    double start_at = 0.0;
    for (int i = 4; i < argc; i++) {
        if (!strcmp(argv[i], "--out-fd") && i + 1 < argc)
            out_fd = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--byte-log") && i + 1 < argc)
            byte_log = fopen(argv[++i], "wb");
        else if (!strcmp(argv[i], "--step-log") && i + 1 < argc)
            step_log = fopen(argv[++i], "wb");
        else if (!strcmp(argv[i], "--realtime"))
            realtime = 1;
        else if (!strcmp(argv[i], "--start-at") && i + 1 < argc)
            start_at = strtod(argv[++i], NULL);
        else {
            fprintf(stderr, "turret_hil: unknown argument %s\n", argv[i]);
            return 2;
        }
    }
    if (strcmp(argv[2], "-"))
        load_schedule(argv[2]);
    else {
        schedule_fd = dup(0);
        fcntl(schedule_fd, F_SETFL, fcntl(schedule_fd, F_GETFL) | O_NONBLOCK);
    }
    if (out_fd == 1) /* the bytes keep the original stdout */
        out_fd = dup(1);
    dup2(2, 1); /* simavr prints its own messages on stdout: they go to stderr */

    elf_firmware_t firmware;
    memset(&firmware, 0, sizeof firmware);
    if (elf_read_firmware(argv[1], &firmware) != 0) {
        fprintf(stderr, "turret_hil: cannot read %s\n", argv[1]);
        return 2;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) {
        fprintf(stderr, "turret_hil: simavr has no atmega328p\n");
        return 2;
    }
    avr_init(avr);
    firmware.frequency = CPU_HZ;
    avr_load_firmware(avr, &firmware);
    avr->frequency = CPU_HZ;
    avr->log = LOG_ERROR;
    avr->sleep = sleep_none;

    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)AVR_UART_FLAG_STDIO; /* the bytes are binary frames, not console lines */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), on_uart_byte,
                            NULL);
    if (step_log)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 3), on_step_pin, NULL);
    pins[0] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 0);
    pins[1] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    /* no level before the firmware's set-up: at reset INT0 is low-level triggered, and simavr would
     * keep raising it while the pin stays low (the schedule sets both pins low once the firmware runs) */
    arm_injection();

    double started = wall_s();
    if (start_at > 0.0) {
        struct timespec now;
        clock_gettime(CLOCK_REALTIME, &now);
        started += start_at - ((double)now.tv_sec + (double)now.tv_nsec * 1e-9);
    }
    uint64_t next_check = 0;
    while (end_cycle ? avr->cycle < end_cycle : !schedule_ended) {
        int state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed) {
            fprintf(stderr, "turret_hil: the firmware stopped (state %d) at cycle %llu\n", state,
                    (unsigned long long)avr->cycle);
            flush_out(UINT64_MAX);
            return 1;
        }
        if (avr->cycle >= next_check) {
            next_check = avr->cycle + CPU_HZ / 1000; /* every emulated millisecond */
            if (schedule_fd >= 0)
                read_schedule();
            if (realtime)
                pace(started, LEAD_S);
            else
                flush_out(UINT64_MAX);
        }
    }
    if (realtime)
        pace(started, 0.0); /* the last bytes at their time */
    flush_out(UINT64_MAX);
    if (byte_log)
        fclose(byte_log);
    if (step_log)
        fclose(step_log);
    fprintf(stderr, "turret_hil: cycles %llu wall_s %.3f bytes %llu lost %llu\n", (unsigned long long)avr->cycle,
            wall_s() - started, (unsigned long long)bytes_out, (unsigned long long)bytes_lost);
    return 0;
}

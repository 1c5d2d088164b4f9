/*
 * Run a beacon firmware image in simavr (Debian's libsimavr) and print its output pins' transitions
 * with the exact cycle at which each happened. The image is the one flashed on the board: the MCU and
 * clock are set here, nothing in the image is simulator-specific.
 *
 *   beacon_sim -f beacon.elf -n CYCLES [-w B1]... [-d C0=1]... [-m atmega328p] [-c 16000000]
 *
 *   -w PORTBIT  watch an output pin (port letter and bit): prints "pin B1 <cycle> <level>" at each change
 *   -o 1A       watch a timer's compare output (timer 1, compare A): prints "compare 1A <cycle> <level>"
 *               with the cycle of the compare match itself. simavr notices a timer event at the end of
 *               the instruction or sleep step that passes it, so a pin's report can come one cycle
 *               late; the match cycle is read back from the timer's state (the overflow base plus the
 *               compare's offset), which is the instant the real chip's pin toggles.
 *   -d PIN=V    hold an input pin at V (0 or 1) from the outside, whatever the pull-up (a jumper to GND
 *               is C0=0); a pin not held reads its pull-up (1) when the firmware turns that on
 * At the end: "register <name> <value>" for the carrier timer's registers, and "end <cycle> <state>".
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <avr_ioport.h>
#include <avr_timer.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_io.h>

#define MAX_PINS 16
/* Ports A..L */
#define PORT_COUNT 12

typedef struct {
    avr_t *avr;
    char name[3];
    int last_level; /* -1 before the first report */
} watched_pin_t;

typedef struct {
    avr_timer_t *timer;
    int compare;
    char name[3];
    int last_level;
} watched_compare_t;

/* Data-space addresses of the ATmega328P registers reported at the end (datasheet, register summary). */
static const struct {
    const char *name;
    uint16_t address;
} reported_registers[] = {
    {"DDRB", 0x24}, {"DDRD", 0x2A}, {"TCCR0A", 0x44}, {"TCCR0B", 0x45}, {"OCR0A", 0x47},
    {"OCR0B", 0x48}, {"TCCR1A", 0x80}, {"TCCR1B", 0x81},
};

static void on_pin_change(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    watched_pin_t *pin = param;
    /* simavr notifies a timer-driven pin twice (compare output, then the port write): report changes */
    if ((int)(value & 1U) == pin->last_level) {
        return;
    }
    pin->last_level = (int)(value & 1U);
    printf("pin %s %llu %u\n", pin->name, (unsigned long long)pin->avr->cycle, value & 1U);
}

static void on_compare_output(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    watched_compare_t *output = param;
    if ((int)(value & 1U) == output->last_level) {
        return;
    }
    output->last_level = (int)(value & 1U);
    const avr_timer_t *timer = output->timer;
    uint64_t match_cycle = timer->tov_base + timer->comp[output->compare].comp_cycles;
    if (match_cycle > timer->io.avr->cycle) {
        match_cycle -= timer->tov_cycles; /* a match at TOP is dispatched after the base moved on */
    }
    printf("compare %s %llu %u\n", output->name, (unsigned long long)match_cycle, value & 1U);
}

/* simavr's timer module named `name` ('0', '1', '2'), found among the MCU's peripherals. */
static avr_timer_t *find_timer(avr_t *avr, char name)
{
    for (avr_io_t *io = avr->io_port; io != NULL; io = io->next) {
        if (io->kind != NULL && strcmp(io->kind, "timer") == 0 && ((avr_timer_t *)io)->name == name) {
            return (avr_timer_t *)io;
        }
    }
    return NULL;
}

static int parse_pin(const char *text, char *port, int *bit)
{
    if (strlen(text) < 2 || text[0] < 'A' || text[0] > 'L' || text[1] < '0' || text[1] > '7') {
        return -1;
    }
    *port = text[0];
    *bit = text[1] - '0';
    return 0;
}

static avr_irq_t *pin_irq(avr_t *avr, char port, int bit)
{
    return avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), bit);
}

static void usage(const char *program)
{
    fprintf(stderr, "usage: %s -f FIRMWARE.elf -n CYCLES [-w B1]... [-o 1A]... [-d C0=1]... [-m MCU] [-c HZ]\n",
            program);
    exit(2);
}

int main(int argc, char **argv)
{
    const char *firmware_path = NULL;
    const char *mcu_name = "atmega328p";
    unsigned long long cycle_limit = 0;
    unsigned long frequency_hz = 16000000UL;
    const char *watched[MAX_PINS];
    const char *driven[MAX_PINS];
    const char *compares[MAX_PINS];
    int compare_count = 0;
    int watched_count = 0;
    int driven_count = 0;
    int option;
    while ((option = getopt(argc, argv, "f:n:w:o:d:m:c:")) != -1) {
        switch (option) {
        case 'f': firmware_path = optarg; break;
        case 'n': cycle_limit = strtoull(optarg, NULL, 10); break;
        case 'w':
            if (watched_count == MAX_PINS) usage(argv[0]);
            watched[watched_count++] = optarg;
            break;
        case 'o':
            if (compare_count == MAX_PINS) usage(argv[0]);
            compares[compare_count++] = optarg;
            break;
        case 'd':
            if (driven_count == MAX_PINS) usage(argv[0]);
            driven[driven_count++] = optarg;
            break;
        case 'm': mcu_name = optarg; break;
        case 'c': frequency_hz = strtoul(optarg, NULL, 10); break;
        default: usage(argv[0]);
        }
    }
    if (firmware_path == NULL || cycle_limit == 0) {
        usage(argv[0]);
    }

    elf_firmware_t firmware;
    memset(&firmware, 0, sizeof firmware);
    if (elf_read_firmware(firmware_path, &firmware) != 0) {
        fprintf(stderr, "cannot read %s\n", firmware_path);
        return 1;
    }
    avr_t *avr = avr_make_mcu_by_name(mcu_name);
    if (avr == NULL) {
        fprintf(stderr, "simavr does not know the MCU %s\n", mcu_name);
        return 1;
    }
    avr_init(avr);
    avr_load_firmware(avr, &firmware);
    avr->frequency = frequency_hz;

    /* simavr's "external" pin state wins over the internal pull-up, as a jumper to GND does. */
    avr_ioport_external_t held[PORT_COUNT];
    memset(held, 0, sizeof held);
    for (int k = 0; k < driven_count; k++) {
        char port;
        int bit;
        const char *equals = strchr(driven[k], '=');
        if (parse_pin(driven[k], &port, &bit) != 0 || equals == NULL) usage(argv[0]);
        avr_ioport_external_t *state = &held[port - 'A'];
        state->name = (unsigned)port;
        state->mask |= 1U << bit;
        if (atoi(equals + 1) & 1) {
            state->value |= 1U << bit;
        }
    }
    for (int k = 0; k < PORT_COUNT; k++) {
        if (held[k].mask != 0 && avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('A' + k), &held[k]) != 0) {
            fprintf(stderr, "the MCU has no port %c\n", 'A' + k);
            return 1;
        }
    }
    static watched_pin_t pins[MAX_PINS];
    for (int k = 0; k < watched_count; k++) {
        char port;
        int bit;
        if (parse_pin(watched[k], &port, &bit) != 0) usage(argv[0]);
        pins[k].avr = avr;
        memcpy(pins[k].name, watched[k], 2);
        pins[k].name[2] = '\0';
        pins[k].last_level = -1;
        avr_irq_register_notify(pin_irq(avr, port, bit), on_pin_change, &pins[k]);
    }

    static watched_compare_t outputs[MAX_PINS];
    for (int k = 0; k < compare_count; k++) {
        const char *text = compares[k];
        if (strlen(text) != 2 || text[1] < 'A' || text[1] > 'C') usage(argv[0]);
        outputs[k].timer = find_timer(avr, text[0]);
        if (outputs[k].timer == NULL) {
            fprintf(stderr, "the MCU has no timer %c\n", text[0]);
            return 1;
        }
        outputs[k].compare = text[1] - 'A';
        memcpy(outputs[k].name, text, 2);
        outputs[k].name[2] = '\0';
        outputs[k].last_level = -1;
        avr_irq_register_notify(outputs[k].timer->io.irq + TIMER_IRQ_OUT_COMP + outputs[k].compare,
                                on_compare_output, &outputs[k]);
    }

    int state = cpu_Running;
    while (avr->cycle < cycle_limit && state != cpu_Done && state != cpu_Crashed) {
        state = avr_run(avr);
    }
    for (size_t k = 0; k < sizeof reported_registers / sizeof reported_registers[0]; k++) {
        printf("register %s %u\n", reported_registers[k].name, avr->data[reported_registers[k].address]);
    }
    printf("end %llu %d\n", (unsigned long long)avr->cycle, state);
    return state == cpu_Crashed ? 1 : 0;
}

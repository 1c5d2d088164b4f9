/*
 * BeAMS beacon firmware for an ATmega328P at 16 MHz (Arduino Uno / Nano class).
 *
 * The beacon sends its code continuously, with no synchronisation to any receiver (thesis section 2.4.4):
 * one period of On-Off-Keying bits, repeated forever, every bit lasting the project's bit time T_b
 * (30.8 us: 14 periods of the TSOP7000's 455 kHz carrier, section 2.4.4 constraint 1).
 *
 * Outputs (docs/beacon_firmware.md has the wiring):
 *   OC1A (PB1, Arduino D9): the envelope, 1 during a burst. Timer1 toggles it in hardware on compare
 *     match, so every edge falls on its timer cycle whatever the CPU does; the compare interrupt only
 *     schedules the next edge, one whole run ahead.
 *   OC0B (PD5, Arduino D5): the carrier, 16 MHz / 35 = 457.1 kHz, duty 18/35, free-running. The IR LED
 *     is driven by envelope AND carrier (two transistors in series, or a 74HC08 gate).
 *   PB5 (Arduino D13, the on-board LED): on while emitting; blinking when the code selection is invalid
 *     (the beacon then stays dark rather than send a code the robot would misread).
 *
 * The code (read once, at reset):
 *   -DBEACON_BITS="\"11111001111100\""  a custom code, sent as written (pins ignored);
 *   -DBEACON_CODE=i                      the family code C_i of eq. 2.6 (pins ignored);
 *   otherwise                            C_i with i read on PC0..PC3 (Arduino A0..A3, internal pull-ups):
 *                                        a jumper to GND sets the bit, i = sum of 2^k over jumpered PCk.
 *   -DBEACON_CODE_COUNT=Nc               the family size (default 5): C_i = [1^i 0 1^(2Nc-i) 0].
 *   -DBEACON_BIT_TIME_NS=30800           the bit time (ns).
 *
 * Timing: a run of n bits lasts n * F_CPU * T_b cycles, 492.8 cycles per bit at 16 MHz and 30.8 us.
 * The fractional part is carried from run to run (a Bresenham accumulator), so every edge falls within
 * one cycle (62.5 ns, Timer1's tick at prescaler 1) of its ideal instant and the code never drifts.
 */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <stdbool.h>
#include <stdint.h>
#include <util/delay.h>

#ifndef BEACON_CODE_COUNT
#define BEACON_CODE_COUNT 5
#endif
#ifndef BEACON_BIT_TIME_NS
#define BEACON_BIT_TIME_NS 30800UL
#endif

/* Section 2.5.2: up to 9 codes in the family. */
#if BEACON_CODE_COUNT < 1 || BEACON_CODE_COUNT > 9
#error "BEACON_CODE_COUNT must be in 1..9 (thesis section 2.5.2)"
#endif
#if defined(BEACON_CODE) && (BEACON_CODE < 1 || BEACON_CODE > BEACON_CODE_COUNT)
#error "BEACON_CODE must be in 1..BEACON_CODE_COUNT"
#endif
/* The bit time as the fraction CYCLES_PER_BIT_NUMERATOR / 1e6 cycles; the product must fit 32 bits. */
#if (F_CPU % 1000UL) != 0
#error "F_CPU must be a whole number of kHz"
#endif
#define CYCLES_PER_BIT_NUMERATOR ((F_CPU / 1000UL) * BEACON_BIT_TIME_NS)
#define CYCLES_PER_BIT_DENOMINATOR 1000000UL
#if (F_CPU / 1000ULL) * BEACON_BIT_TIME_NS > 0xFFFFFFFFULL
#error "bit time too long for this clock"
#endif

/* Each build uses one way of choosing the code; the others still compile (and are checked), unused. */
#define ONE_OF_THE_CODE_SOURCES __attribute__((unused))

/* Runs (bursts and gaps) in one code period; a family code has four. */
#define MAX_RUNS 32
/* A run's cycle count must fit Timer1's 16 bits with room for the interrupt that schedules it. */
#define MAX_RUN_CYCLES 60000UL
/* Shortest run the compare interrupt can schedule in time: it writes the next match about 100 cycles
 * (wake-up, 36 pushes and pops, the 32-bit sum) after this one; a bit is 492.8 cycles. */
#define MIN_RUN_CYCLES 250UL
/* First edge this many cycles after Timer1 starts. */
#define FIRST_EDGE_CYCLES 1000U

/* Carrier: Timer0 fast PWM with TOP = OCR0A, OC0B cleared on compare: F_CPU / (TOP + 1). */
#define CARRIER_TOP 34U
#define CARRIER_HIGH_CYCLES 18U

#define SELECT_PINS_MASK 0x0FU
#define LED_BIT PB5
#define ENVELOPE_BIT PB1
#define CARRIER_BIT PD5

/* The schedule the compare interrupt walks: run k lasts run_cycles[k] cycles plus
 * run_fraction[k] / cycle_denominator, the fraction carried by fraction_accumulator. */
static uint16_t run_cycles[MAX_RUNS];
static uint32_t run_fraction[MAX_RUNS];
static uint32_t cycle_denominator;
static uint8_t run_count;
static uint8_t run_index;
static uint32_t fraction_accumulator;

/* Clear the reset cause and stop the watchdog before main: after a watchdog reset it stays enabled. */
void clear_watchdog_at_reset(void) __attribute__((naked, used, section(".init3")));
void clear_watchdog_at_reset(void)
{
    MCUSR = 0;
    wdt_disable();
}

static uint32_t greatest_common_divisor(uint32_t a, uint32_t b)
{
    while (b != 0) {
        uint32_t remainder = a % b;
        a = b;
        b = remainder;
    }
    return a;
}

/* Bit lengths of the runs of a cyclic bit string, starting with the burst that follows a gap (the order
 * of beams_driver.codes.BeaconCode.runs_bits). Returns the number of runs, 0 when the string is not a
 * code (a character other than 0 and 1, no 0 or no 1) or has too many runs. */
ONE_OF_THE_CODE_SOURCES static uint8_t runs_of_bits(const char *bits, uint8_t *run_bits)
{
    uint8_t length = 0;
    while (bits[length] != '\0') {
        if ((bits[length] != '0' && bits[length] != '1') || length == UINT8_MAX) {
            return 0;
        }
        length++;
    }
    uint8_t start = length; /* the first 1 preceded (cyclically) by a 0 */
    for (uint8_t k = 0; k < length; k++) {
        if (bits[k] == '1' && bits[(k + length - 1) % length] == '0') {
            start = k;
            break;
        }
    }
    if (start == length) {
        return 0;
    }
    uint8_t count = 0;
    for (uint8_t k = 0; k < length; k++) {
        char bit = bits[(start + k) % length];
        if (k > 0 && bit == bits[(start + k - 1) % length]) {
            run_bits[count - 1]++;
        } else if (count == MAX_RUNS) {
            return 0;
        } else {
            run_bits[count++] = 1;
        }
    }
    return count;
}

/* C_i of eq. 2.6: [1^i 0 1^(2Nc-i) 0] as runs burst i, gap 1, burst 2Nc-i, gap 1. */
ONE_OF_THE_CODE_SOURCES static uint8_t runs_of_family_code(uint8_t index, uint8_t *run_bits)
{
    if (index < 1 || index > BEACON_CODE_COUNT) {
        return 0;
    }
    run_bits[0] = index;
    run_bits[1] = 1;
    run_bits[2] = 2 * BEACON_CODE_COUNT - index;
    run_bits[3] = 1;
    return 4;
}

/* The family index set by the jumpers on PC0..PC3 (to GND = 1), read with the pull-ups on. */
ONE_OF_THE_CODE_SOURCES static uint8_t selected_code_index(void)
{
    DDRC &= (uint8_t)~SELECT_PINS_MASK;
    PORTC |= SELECT_PINS_MASK;
    _delay_us(100); /* the pull-ups charge the pin capacitance */
    uint8_t index = (uint8_t)~PINC & SELECT_PINS_MASK;
    PORTC &= (uint8_t)~SELECT_PINS_MASK; /* pull-ups off: no current through the jumpers afterwards */
    return index;
}

/* The code's runs (bit lengths), from the build settings or the pins; 0 runs when there is no valid code. */
static uint8_t code_runs(uint8_t *run_bits)
{
#if defined(BEACON_BITS)
    return runs_of_bits(BEACON_BITS, run_bits);
#elif defined(BEACON_CODE)
    return runs_of_family_code(BEACON_CODE, run_bits);
#else
    return runs_of_family_code(selected_code_index(), run_bits);
#endif
}

/* Fill the schedule: run k of n bits lasts n * numerator / denominator cycles, split into whole cycles
 * and a fraction. False when a run is too short or too long for Timer1. */
static bool build_schedule(const uint8_t *run_bits, uint8_t count)
{
    uint32_t divisor = greatest_common_divisor(CYCLES_PER_BIT_NUMERATOR, CYCLES_PER_BIT_DENOMINATOR);
    uint32_t numerator = CYCLES_PER_BIT_NUMERATOR / divisor;
    cycle_denominator = CYCLES_PER_BIT_DENOMINATOR / divisor;
    uint32_t whole_per_bit = numerator / cycle_denominator;
    uint32_t fraction_per_bit = numerator % cycle_denominator;
    for (uint8_t k = 0; k < count; k++) {
        uint32_t fraction = run_bits[k] * fraction_per_bit;
        uint32_t cycles = run_bits[k] * whole_per_bit + fraction / cycle_denominator;
        if (cycles < MIN_RUN_CYCLES || cycles > MAX_RUN_CYCLES) {
            return false;
        }
        run_cycles[k] = (uint16_t)cycles;
        run_fraction[k] = fraction % cycle_denominator;
    }
    /* Half a cycle ahead: each edge is rounded to the nearest cycle rather than truncated. */
    fraction_accumulator = cycle_denominator / 2;
    run_count = count;
    return true;
}

/* An edge has just toggled OC1A: schedule the end of the run it began. */
ISR(TIMER1_COMPA_vect)
{
    uint16_t cycles = run_cycles[run_index];
    fraction_accumulator += run_fraction[run_index];
    if (fraction_accumulator >= cycle_denominator) {
        fraction_accumulator -= cycle_denominator;
        cycles++;
    }
    OCR1A += cycles;
    run_index = (run_index + 1 == run_count) ? 0 : run_index + 1;
}

static void start_carrier(void)
{
    DDRD |= _BV(CARRIER_BIT);
    OCR0A = CARRIER_TOP;
    OCR0B = CARRIER_HIGH_CYCLES - 1;
    TCCR0A = _BV(COM0B1) | _BV(WGM01) | _BV(WGM00); /* fast PWM, OC0B set at BOTTOM, cleared on match */
    TCCR0B = _BV(WGM02) | _BV(CS00);                /* TOP = OCR0A, no prescaler */
}

/* Timer1 free-running at F_CPU; OC1A toggles at each compare match, the first one a burst's start. */
static void start_envelope(void)
{
    TCCR1A = _BV(COM1A0); /* normal mode, toggle OC1A on compare match */
    TCNT1 = 0;
    OCR1A = FIRST_EDGE_CYCLES;
    TIFR1 = _BV(OCF1A);
    TIMSK1 = _BV(OCIE1A);
    TCCR1B = _BV(CS10);
}

/* No valid code: stay dark and blink the LED (the watchdog still guards the loop). */
static void signal_invalid_selection(void)
{
    for (;;) {
        PINB = _BV(LED_BIT); /* writing PINB toggles PORTB */
        _delay_ms(100);
        wdt_reset();
    }
}

int main(void)
{
    /* The envelope pin driven low from the start: a floating pin could light the LED. */
    PORTB &= (uint8_t)~_BV(ENVELOPE_BIT);
    DDRB |= _BV(LED_BIT) | _BV(ENVELOPE_BIT);
    wdt_enable(WDTO_250MS);
    uint8_t run_bits[MAX_RUNS];
    uint8_t count = code_runs(run_bits);
    if (count == 0 || !build_schedule(run_bits, count)) {
        signal_invalid_selection();
    }
    start_carrier();
    start_envelope();
    PORTB |= _BV(LED_BIT);
    set_sleep_mode(SLEEP_MODE_IDLE); /* Timer0 and Timer1 run in idle */
    sei();
    for (;;) {
        sleep_mode();
        wdt_reset(); /* woken by the compare interrupt at least every run */
    }
}

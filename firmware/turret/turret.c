/*
 * BeAMS turret firmware for the ATmega328P (thesis section 2.4): timestamps every edge of the infrared
 * receiver and the optical zero reference on one 2 MHz timer, drives the stepper, and streams the events
 * to the host in the frames of BeAMS serial protocol v2 (src/beams_driver/beams_driver/serial_protocol.py).
 *
 * Pins (Arduino Uno / Nano names in brackets; docs/firmware.md has the wiring):
 *   PB0 (D8)  ICP1  receiver output, Timer1 input capture, edge select toggled at every edge
 *   PD2 (D2)  INT0  optical switch's logic output, zero reference on its rising edge
 *   PB3 (D11) OC2A  stepper driver STEP (Timer2 toggles it in hardware)
 *   PD4 (D4)        stepper driver DIR (low)
 *   PD5 (D5)        stepper driver ENABLE (low: enabled)
 *   PD1 (D1)  TXD   frames to the host, 500000 baud 8N1
 *
 * Interrupts: Timer1 capture (an edge), INT0 (the zero reference), Timer1 compare B (heartbeat, hello),
 * Timer1 overflow (the 32-bit count's high half), Timer2 compare A (the stepper's ramp, then off),
 * USART data register empty (the transmitter). The main loop encodes queued events into frames and
 * sleeps when there is nothing to do.
 *
 * No edge is lost silently: an edge that comes before the capture is armed for it is reported missing
 * (the capture interrupt below; docs/firmware.md).
 */
#include <stdbool.h>
#include <stdint.h>

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/crc16.h>

#include "config.h"

_Static_assert(F_CPU % (8UL * BAUD_RATE) == 0, "the baud rate must be exact from F_CPU (U2X)");
_Static_assert(HALF_STEP_TICKS * 2UL * STEPS_PER_REVOLUTION * TURN_RATE_MILLIHZ == TIMER_HZ * 1000UL,
               "the turn rate must be a whole number of Timer1 ticks per STEP half-period");
_Static_assert(HALF_STEP_TICKS >= 2 && HALF_STEP_TICKS <= 256, "STEP half-period must be 2..256 ticks");
_Static_assert((EVENT_QUEUE_LENGTH & (EVENT_QUEUE_LENGTH - 1)) == 0 && EVENT_QUEUE_LENGTH <= 128,
               "EVENT_QUEUE_LENGTH: a power of two, at most 128");
_Static_assert((TX_QUEUE_LENGTH & (TX_QUEUE_LENGTH - 1)) == 0, "TX_QUEUE_LENGTH: a power of two");

enum event_kind {
    KIND_RISING = 0x01,
    KIND_FALLING = 0x02,
    KIND_ZERO_REFERENCE = 0x03,
    KIND_HEARTBEAT = 0x04,
    KIND_MISSED_EDGE = 0x05,
    KIND_HELLO = 0x10,
};

#define SYNC_1 0xA5
#define SYNC_2 0x5B
#define HELLO_FLAG_BOOT 0x01

struct event {
    uint8_t kind;
    uint8_t sequence;
    uint16_t low, high; /* the 32-bit count in halves: the interrupts need no 32-bit arithmetic */
};

/* ---- the event queue: filled by the interrupts, emptied by the main loop ---- */

static struct event event_queue[EVENT_QUEUE_LENGTH];
static volatile uint8_t event_head; /* written by the interrupts only */
static volatile uint8_t event_tail; /* written by the main loop only */
static uint8_t next_sequence;       /* numbered at capture: a dropped event leaves a gap */
static volatile uint32_t dropped_events;
static volatile uint16_t timer_high; /* Timer1 overflows: the high half of the 32-bit count */
static uint8_t heartbeats;

/* Called with interrupts disabled (from an ISR). */
static inline __attribute__((always_inline)) void push_event(uint8_t kind, uint16_t low, uint16_t high)
{
    uint8_t head = event_head;
    uint8_t next = (uint8_t)((head + 1U) & (EVENT_QUEUE_LENGTH - 1U));
    uint8_t sequence = next_sequence++;
    if (next == event_tail) {
        dropped_events++; /* the host sees the gap in the sequence numbers */
        return;
    }
    event_queue[head].kind = kind;
    event_queue[head].sequence = sequence;
    event_queue[head].low = low;
    event_queue[head].high = high;
    event_head = next;
}

/*
 * The high half of the 32-bit count of a 16-bit Timer1 value latched in this ISR. An overflow may be
 * pending (TOV1 set, its ISR not run yet because this one runs first): it happened before the latch when
 * the latched value is small (the counter wrapped, then latched), after it when large (latched near the
 * top, then wrapped).
 */
static inline __attribute__((always_inline)) uint16_t high_of(uint16_t low)
{
    uint16_t high = timer_high;
    if ((TIFR1 & _BV(TOV1)) && low < 0x8000U)
        high++;
    return high;
}

/* The head's ICR1 and pin just after the toggle, for the tail; the TCCR1B the head writes (the tail's). */
static volatile uint16_t capture_count;
static volatile uint8_t capture_pin;
static volatile uint8_t next_control;

/* The head reads ICR1, then arms the other edge (14 cycles after the vector) and samples the pin. None
 * of its instructions changes SREG. */
ISR(TIMER1_CAPT_vect, ISR_NAKED)
{
    asm volatile("push r24\n\t"
                 "lds r24, %[icr_low]\n\t" /* the low byte first: it latches the high byte */
                 "sts capture_count, r24\n\t"
                 "lds r24, %[icr_high]\n\t"
                 "sts capture_count + 1, r24\n\t"
                 "lds r24, next_control\n\t"
                 "sts %[control], r24\n\t"
                 "in r24, %[pin]\n\t"
                 "sts capture_pin, r24\n\t"
                 "pop r24\n\t"
                 "jmp __vector_capture_tail" ::[icr_low] "i"(_SFR_MEM_ADDR(ICR1L)),
                 [icr_high] "i"(_SFR_MEM_ADDR(ICR1H)), [control] "i"(_SFR_MEM_ADDR(TCCR1B)),
                 [pin] "i"(_SFR_IO_ADDR(PINB)));
}

/* The tail, an interrupt handler only the head jumps to: a pin that already left the captured edge's
 * level means the next edge came before it was armed for. It reports the edge, then one missed-edge
 * event per edge missed, and arms for the edge the pin now allows. The datasheet asks to clear ICF1
 * after a change of the edge select, which may latch the edge already on the pin: the missed case, the
 * only one where ICF1 is cleared (simavr 1.6 clears every pending Timer1 flag on any TIFR1 write). */
ISR(__vector_capture_tail)
{
    uint8_t control = TCCR1B;
    bool level = !(control & _BV(ICES1)); /* armed for the falling edge: the captured one rose */
    bool rising = level;
    uint8_t missed = 0;
    if ((bool)(capture_pin & _BV(PINB0)) != level) {
        if (TIFR1 & _BV(ICF1))
            TIFR1 = _BV(ICF1); /* the chip's latch of the edge on the pin as the edge select changed */
        do { /* an edge came before the edge select was armed for it: arm for the one after */
            level = !level;
            control ^= _BV(ICES1);
            TCCR1B = control;
            missed++;
        } while ((bool)(PINB & _BV(PINB0)) != level && !(TIFR1 & _BV(ICF1)));
    }
    next_control = control ^ _BV(ICES1);
    uint16_t count = capture_count;
    push_event(rising ? KIND_RISING : KIND_FALLING, count, high_of(count));
    while (missed--) {
        count = TCNT1;
        push_event(KIND_MISSED_EDGE, count, high_of(count));
    }
}

ISR(INT0_vect)
{
    uint16_t now = TCNT1; /* as early as the ISR allows: its latency is the zero reference's delay */
    uint16_t high = high_of(now);
    if (now < ZERO_REFERENCE_LATENCY_TICKS)
        high--;
    push_event(KIND_ZERO_REFERENCE, now - ZERO_REFERENCE_LATENCY_TICKS, high);
}

/* Interruptible but for the queue: a capture waits for no more than push_event. OCR1B never changes:
 * once per 65536 ticks, at a count 32768 ticks from any overflow, so timer_high is steady meanwhile. */
ISR(TIMER1_COMPB_vect, ISR_NOBLOCK)
{
    uint8_t kind = (++heartbeats % HELLO_EVERY_HEARTBEATS) == 0 ? KIND_HELLO : KIND_HEARTBEAT;
    uint16_t high = timer_high;
    cli();
    push_event(kind, HEARTBEAT_COMPARE, high);
}

ISR(TIMER1_OVF_vect)
{
    timer_high++;
}

/* ---- the stepper: Timer2 toggles STEP in hardware; this ISR only runs during the ramp ---- */

static uint8_t ramp_countdown = RAMP_TOGGLES_PER_COUNT;

ISR(TIMER2_COMPA_vect)
{
    if (--ramp_countdown)
        return;
    ramp_countdown = RAMP_TOGGLES_PER_COUNT;
    if (TCCR2B & _BV(CS20)) { /* clk/32: the slow start */
        if (OCR2A > 63U) {
            OCR2A--;
        } else { /* the same speed at clk/8, which the last part of the ramp and the cruise need */
            OCR2A = 255U;
            TCCR2B = _BV(CS21);
        }
    } else if (OCR2A > HALF_STEP_TICKS - 1U) {
        OCR2A--;
    } else {
        TIMSK2 = 0; /* at speed: the hardware alone keeps stepping */
    }
}

/* ---- the transmitter: the main loop fills tx_queue, the UDRE interrupt empties it ---- */

static uint8_t tx_queue[TX_QUEUE_LENGTH];
static volatile uint8_t tx_head; /* main loop */
static volatile uint8_t tx_tail; /* UDRE ISR */

ISR(USART_UDRE_vect)
{
    uint8_t tail = tx_tail;
    if (tail == tx_head) {
        UCSR0B &= (uint8_t)~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_queue[tail];
    tx_tail = (uint8_t)((tail + 1U) & (TX_QUEUE_LENGTH - 1U));
}

static uint8_t tx_free(void)
{
    return (uint8_t)((tx_tail - tx_head - 1U) & (TX_QUEUE_LENGTH - 1U));
}

static uint16_t frame_crc;

static void tx_byte(uint8_t byte, bool in_crc)
{
    if (in_crc)
        frame_crc = _crc_xmodem_update(frame_crc, byte); /* CRC-16/CCITT-FALSE with init 0xFFFF */
    uint8_t head = tx_head;
    tx_queue[head] = byte;
    tx_head = (uint8_t)((head + 1U) & (TX_QUEUE_LENGTH - 1U));
}

static void tx_u32(uint32_t value)
{
    for (uint8_t i = 0; i < 4; i++) {
        tx_byte((uint8_t)value, true);
        value >>= 8;
    }
}

#define EVENT_FRAME_SIZE 10U
#define HELLO_FRAME_SIZE 24U

/* One frame (serial_protocol.py's layout) into tx_queue, which has room for it. */
static void send_frame(const struct event *event)
{
    static bool booted;
    frame_crc = 0xFFFFU;
    tx_byte(SYNC_1, false);
    tx_byte(SYNC_2, false);
    tx_byte(event->kind, true);
    tx_byte(event->sequence, true);
    tx_u32(((uint32_t)event->high << 16) | event->low);
    if (event->kind == KIND_HELLO) {
        cli();
        uint32_t dropped = dropped_events;
        sei();
        tx_byte(PROTOCOL_VERSION, true);
        tx_byte(booted ? 0U : HELLO_FLAG_BOOT, true);
        tx_u32(TIMER_HZ);
        tx_u32(TICKS_PER_REVOLUTION);
        tx_u32(dropped);
        booted = true;
    }
    uint16_t crc = frame_crc;
    tx_byte((uint8_t)crc, false);
    tx_byte((uint8_t)(crc >> 8), false);
    UCSR0B |= _BV(UDRIE0);
}

/* ---- start-up ---- */

static void setup(void)
{
    /* STEP, DIR, ENABLE outputs (driver enabled, one direction); the receiver and the switch inputs */
    DDRB = _BV(DDB3);
    DDRD = _BV(DDD4) | _BV(DDD5) | _BV(DDD1);
    PORTD = 0; /* DIR and ENABLE low; no pull-ups: the receiver and the switch drive their pins */

    UCSR0A = _BV(U2X0); /* before UBRR0: simavr computes the link's speed when UBRR0 is written */
    UBRR0 = UBRR_VALUE;
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00); /* 8N1 */
    UCSR0B = _BV(TXEN0);

    EICRA = _BV(ISC01) | _BV(ISC00); /* INT0 on the rising edge */
    EIMSK = _BV(INT0);

    /* Timer2: CTC, toggle OC2A on compare, clk/32, the slowest step rate first */
    OCR2A = 255U;
    TCCR2A = _BV(COM2A0) | _BV(WGM21);
    TIMSK2 = _BV(OCIE2A);
    TCCR2B = _BV(CS21) | _BV(CS20);

    /* Timer1: normal mode, clk/8; the first capture waits for the edge the pin's level allows */
    OCR1B = HEARTBEAT_COMPARE;
    TIMSK1 = _BV(ICIE1) | _BV(OCIE1B) | _BV(TOIE1);
    TCCR1B = ((PINB & _BV(PINB0)) ? 0U : _BV(ICES1)) | _BV(CS11);
    next_control = TCCR1B ^ _BV(ICES1);

    push_event(KIND_HELLO, 0, 0); /* the boot hello, before any capture */
    set_sleep_mode(SLEEP_MODE_IDLE);
}

int main(void)
{
    setup();
    sei();
    for (;;) {
        cli();
        uint8_t tail = event_tail;
        if (tail == event_head || tx_free() < HELLO_FRAME_SIZE) {
            /* nothing to send, or no room: sleep until an interrupt (sei; sleep is atomic) */
            sleep_enable();
            sei();
            sleep_cpu();
            sleep_disable();
            continue;
        }
        sei();
        struct event event = event_queue[tail]; /* the producers never touch the tail's slot */
        event_tail = (uint8_t)((tail + 1U) & (EVENT_QUEUE_LENGTH - 1U));
        send_frame(&event);
    }
}

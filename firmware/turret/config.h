/*
 * The turret board's configuration: clock, link, stepper. Every value may be overridden at build time,
 * e.g. `make -C firmware TURRET_FLAGS='-DSTEPS_PER_REVOLUTION=1600 -DTURN_RATE_MILLIHZ=5000'`.
 * The host learns the timer frequency and the ticks per revolution from the hello frame
 * (beams_driver/serial_protocol.py), so it needs no change when these do.
 */
#ifndef TURRET_CONFIG_H
#define TURRET_CONFIG_H

#ifndef F_CPU
#define F_CPU 16000000UL /* the ATmega328P's crystal (Arduino Uno / Nano) */
#endif

/* Timer1, the common timer: F_CPU / 8 = 2 MHz, 0.5 us per tick (the thesis's PIC: 625 kHz). */
#define TIMER1_PRESCALER 8UL
#define TIMER_HZ (F_CPU / TIMER1_PRESCALER)

/* The link: 500000 baud is exact from 16 MHz (U2X, UBRR 3); 460800 would be 8.5% off. */
#ifndef BAUD_RATE
#define BAUD_RATE 500000UL
#endif
#define UBRR_VALUE (F_CPU / (8UL * BAUD_RATE) - 1UL)

/* The stepper driver's STEP input counts microsteps: a 200-step motor at 1/4 microstepping. */
#ifndef STEPS_PER_REVOLUTION
#define STEPS_PER_REVOLUTION 800UL
#endif
/* The turret's speed in mHz (turns per 1000 s): 10 turns/s, the thesis's rate. */
#ifndef TURN_RATE_MILLIHZ
#define TURN_RATE_MILLIHZ 10000UL
#endif

/* STEP is Timer2's OC2A, toggled by the hardware every HALF_STEP_TICKS Timer1 ticks (CTC, clk/8). */
#define HALF_STEP_TICKS (TIMER_HZ * 1000UL / (2UL * STEPS_PER_REVOLUTION * TURN_RATE_MILLIHZ))
#define TICKS_PER_REVOLUTION (2UL * STEPS_PER_REVOLUTION * HALF_STEP_TICKS)

/* The ramp from standstill: one OCR2A count less every RAMP_TOGGLES_PER_COUNT toggles (about 1.2 s). */
#ifndef RAMP_TOGGLES_PER_COUNT
#define RAMP_TOGGLES_PER_COUNT 16U
#endif

/* Events captured but not yet sent (a power of two): 128 x 6 bytes of the 2 KiB RAM. */
#ifndef EVENT_QUEUE_LENGTH
#define EVENT_QUEUE_LENGTH 128U
#endif
/* Bytes queued for the UART (a power of two, at least one hello frame). */
#define TX_QUEUE_LENGTH 64U

/* Heartbeat: Timer1 compare B at a fixed OCR1B, once per 65536 ticks (32.8 ms at 2 MHz);
 * every HELLO_EVERY_HEARTBEATS-th one is a hello (every 262 ms: a host that opens the port mid-stream
 * waits no longer for the clock). */
#define HEARTBEAT_COMPARE 0x8000U
#define HELLO_EVERY_HEARTBEATS 8U

/* Cycles from the switch's edge to INT0's read of TCNT1 (the interrupt response, the jump and the ISR's
 * prologue: 37 cycles, 4.6 ticks), taken off the zero reference's count; another interrupt running when
 * the switch fires delays it further (docs/firmware.md: at most the longest ISR, 20 ticks). */
#define ZERO_REFERENCE_LATENCY_TICKS 4U

#define PROTOCOL_VERSION 2U

#endif

/* Hardware layer: UART with ring buffers, the clock (Timer1), timed ADC integration (Timer0 + ADC), pins. */
#ifndef DETECTOR_HW_H
#define DETECTOR_HW_H

#include <stdint.h>

/* What the emulation harness (simulator/devices/avr_harness.c) reads from RAM by this symbol's address; no
 * effect on a real board. busy: the board has work (a command, a reading, bytes to send); first: set for the
 * first repeat of a reading; n: repeats of the reading; nconv: conversions per repeat (per half when chopped);
 * source, gain: state; chop: the reading is chopped (the source switches within each repeat). */
struct fw_probe {
    uint8_t busy;
    uint8_t first;
    uint8_t source;
    uint8_t gain;
    uint16_t n;
    uint32_t nconv;
    uint8_t chop;
};
extern volatile struct fw_probe fw_probe;

void hw_init(void);
const char *hw_reset_cause(void);

/* UART */
int16_t uart_getc(void);                /* -1 when nothing was received */
uint8_t uart_rx_overflowed(void);       /* bytes were lost since the last call (ring full, overrun, framing) */
void uart_putc(char c);
void uart_puts(const char *s);
void uart_puts_P(const char *s);        /* string in flash (PSTR) */
void uart_put_u64(uint64_t v);
void uart_put_fixed(uint64_t v, uint8_t decimals);  /* v / 10^decimals with all the decimals */
void uart_put_seconds_us(uint64_t us);  /* seconds, trailing zeros dropped (0.000125, 0.01, 10) */
void idle_until_input(void);            /* sleep until a byte arrives (clears busy while nothing is pending) */

/* clock: microseconds since power-up (4 us resolution) */
uint64_t clock_us(void);
void sleep_us(uint32_t us);

/* pins */
void set_source(uint8_t on);
void set_gain_index(uint8_t i);
void set_reference(uint8_t in_beam);   /* the sample changer's pin */

/* the on-board LED (D13), lit while a repeat integrates: the emulation harness sets the amplifier's output for
 * the repeat at its rising edge */
void repeat_led(uint8_t on);

/* Sum of nconv conversions of the amplifier (channel ADC_CHANNEL, or the ADS1115 when built with ADC=ads1115) or of
 * the monitor (MONITOR_CHANNEL, the ATmega's ADC), one every SAMPLE_PERIOD_US; *clipped set when one read at or
 * above CLIP_COUNT (the amplifier's swing) or at the ADS1115's limits. Returns 0 with *fault set when the
 * ADS1115 does not answer. */
int32_t integrate(uint8_t channel, uint32_t nconv, uint8_t *clipped, uint8_t *fault);

/* ADC=ads1115: 1 when the ADS1115 acknowledges its address (always 1 on the ATmega's own ADC) */
uint8_t adc_present(void);

#endif

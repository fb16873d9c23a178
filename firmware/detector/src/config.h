/* gonio-brdf detector board: build-time settings and the pin map (ATmega328P at 16 MHz, Arduino Uno/Nano).
 *
 * Pin map (Arduino name / AVR pin):
 *   A0  / PC0  photodiode amplifier (TIA) output, 0..5 V, read by the ADC against AVcc
 *   D7  / PD7  source on (high) / off (low): gate of the logic-level MOSFET that switches the lamp or LED
 *   D8  / PB0  gain select A  \
 *   D9  / PB1  gain select B   > address of the 8:1 analog multiplexer (74HC4051 / CD4051 / ADG708) that puts
 *   D10 / PB2  gain select C  /  one feedback resistor across the TIA: gain index i selects channel i
 *   D6  / PD6  (built with SAMPLE_CHANGER=1 only) white reference in the beam (high) / sample (low): drives the
 *              sample changer (a flip-in reference on a solenoid or hobby servo board)
 *   D13 / PB5  on-board LED: lit while a repeat integrates
 *   D0/D1      UART to the USB bridge, 115200 baud 8N1 (U2X)
 */
#ifndef DETECTOR_CONFIG_H
#define DETECTOR_CONFIG_H

#define FW_NAME "gonio-detector"
#define FW_VERSION "0.1.0"

#define MAX_LINE 256          /* characters of a command line (protocol); longer: error:4 */
#define MAX_REPEATS 1000      /* READ/DARK n */
#define DEFAULT_REPEATS 4     /* READ/DARK without n */

/* The ADC samples every SAMPLE_PERIOD_US (Timer0), a conversion takes 13 ADC clocks of 8 us (prescaler 128):
 * 104 us. The integration time of a repeat is a whole number of sample periods; its reading is the sum of the
 * conversions (counts up to 1023 per conversion). */
#define SAMPLE_PERIOD_US 125UL
#define DEFAULT_NCONV 80UL    /* 0.01 s */
#define MAX_NCONV 80000UL     /* 10 s (the protocol's longest INT) */
#define MIN_INT_NS 10000ULL   /* 1e-5 s: the protocol's shortest INT, rounded up to one sample period */
#define MAX_INT_NS 10000000000ULL

/* Wait after switching the source or the gain before integrating (LED and amplifier settling), microseconds. */
#define SETTLE_US 2000UL

/* Wait after a gain switch before integrating, microseconds: what the amplifier needs (until detector.c waits it
 * after a gain switch, it waits SETTLE_US after any switch). The amplifier (hardware/frontend/frontend.cir,
 * Rf x Cf = 100 us on every range) settles to 0.1 % within 0.8 ms, except from the 100 M range down to the 10 M
 * one: the idle 100 M channel's 6 pF (its capacitor and the multiplexer pin's) discharges through 100 M into the
 * summing node, 2.3 ms. tests/test_frontend_spice.py checks every range against this value;
 * `python hardware/frontend/simulate.py --figures` prints the times. */
#define GAIN_SETTLE_US 2500UL

/* The amplifier's gains, by multiplexer channel (index 0 = channel 0): relative to the lowest feedback
 * resistor; at most 8. Override with make GAINS=1,10,100 */
#ifndef GAIN_LIST
#define GAIN_LIST 1, 10, 100, 1000, 10000
#endif

#define SOURCE_DDR DDRD
#define SOURCE_PORT PORTD
#define SOURCE_BIT PD7
#define GAIN_DDR DDRB
#define GAIN_PORT PORTB
#define GAIN_MASK 0x07        /* PB0..PB2 */
#define LED_DDR DDRB
#define LED_PORT PORTB
#define LED_BIT PB5
#define ADC_CHANNEL 0
#define CHANGER_DDR DDRD
#define CHANGER_PORT PORTD
#define CHANGER_BIT PD6

/* A sample changer (make SAMPLE_CHANGER=1): SAMPLE REF/TARGET drive D6 and wait CHANGER_SETTLE_MS for it to
 * move. Without one (the default), SAMPLE answers error:10 and gonio-capture asks the operator to swap. */
#ifndef SAMPLE_CHANGER
#define SAMPLE_CHANGER 0
#endif
#define CHANGER_SETTLE_MS 300UL

#endif

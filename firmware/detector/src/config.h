/* gonio-brdf detector board: build-time settings and the pin map (ATmega328P at 16 MHz, Arduino Uno/Nano).
 *
 * Pin map (Arduino name / AVR pin):
 *   A0  / PC0  photodiode amplifier (TIA) output, 0..5 V, read by the ADC against AVcc
 *   A1  / PC1  (built with MONITOR=1) the monitor photodiode's amplifier: a second photodiode that sees the source
 *              directly; READ reports its sum (monitor=) so that the source's and the supply's drift divide out
 *   A4  / PC4  (built with ADC=ads1115) SDA of the ADS1115 16-bit ADC (I2C address 0x48: ADDR to GND)
 *   A5  / PC5  (built with ADC=ads1115) SCL; the ADS1115 reads AIN0 (amplifier output) - AIN1 (its reference)
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

#ifndef ADC_ADS1115
#define ADC_ADS1115 0
#endif

#define FW_NAME "gonio-detector"
#define FW_VERSION "0.1.0"

#define MAX_LINE 256          /* characters of a command line (protocol); longer: error:4 */
#define MAX_REPEATS 1000      /* READ/DARK n */
#define DEFAULT_REPEATS 4     /* READ/DARK without n */

/* The ADC samples every SAMPLE_PERIOD_US (Timer0), a conversion takes 13 ADC clocks of 8 us (prescaler 128):
 * 104 us. The integration time of a repeat is a whole number of sample periods; its reading is the sum of the
 * conversions (counts up to 1023 per conversion). Built with ADC=ads1115 the ADS1115 converts instead, single
 * shot at 860 samples/s (1.163 ms), one conversion every 2 ms (the conversion, polling its end and reading it over
 * I2C at 400 kHz). */
#if ADC_ADS1115
#define SAMPLE_PERIOD_US 2000UL
#define DEFAULT_NCONV 5UL     /* 0.01 s */
#define MAX_NCONV 5000UL      /* 10 s */
#define ADC_BITS 16
#define ADC_FULL 32767L       /* the ADS1115's largest code (+4.096 V at PGA +-4.096 V); -32768 the lowest */
#define CLIP_COUNT 32767L
#else
#define SAMPLE_PERIOD_US 125UL
#define DEFAULT_NCONV 80UL    /* 0.01 s */
#define MAX_NCONV 80000UL     /* 10 s (the protocol's longest INT) */
#define ADC_BITS 10
#define ADC_FULL 1023L
/* The op-amp never reaches 1023: an MCP6001 on 5 V swings to about Vdd - 25 mV. A conversion at or above the
 * count of its swing minus a margin (CLIP_MV, default 4950 mV: 25 mV below the swing) counts as clipped.
 * make CLIP_MV=4900 for an amplifier that swings less. */
#ifndef CLIP_MV
#define CLIP_MV 4950UL
#endif
#define CLIP_COUNT ((long)(1023UL * (CLIP_MV) / 5000UL))
#endif
#define AVR_PERIOD_US 125UL  /* the ATmega's ADC: one conversion every 125 us (also the monitor's, ADC=ads1115) */
#define MIN_INT_NS 10000ULL   /* 1e-5 s: the protocol's shortest INT, rounded up to one sample period */
#define MAX_INT_NS 10000000000ULL

/* Waits before integrating, microseconds: after a gain switch (the amplifier, GAIN_SETTLE_US below) and after the
 * source is switched on or off (SOURCE_SETTLE_US: an LED is at full light within microseconds, 2 ms covers its
 * driver; a halogen lamp's filament takes 100-300 ms to heat and to cool: make SOURCE_SETTLE_MS=300). SETTLE <s>
 * changes the source's at run time (0..10 s). */
#ifndef SOURCE_SETTLE_MS
#define SOURCE_SETTLE_MS 2UL
#endif
#define SOURCE_SETTLE_US ((uint32_t)(SOURCE_SETTLE_MS) * 1000UL)
#define MAX_SETTLE_US 10000000UL

/* Chopping (CHOP ON): the source is switched on and off every CHOP_HALF_US and a repeat is the sum of the "on"
 * halves minus the sum of the "off" halves, each half integrating a whole number of mains periods (after its
 * settle), so room light, its 100 Hz (120 Hz) flicker and the amplifier's offset and drift cancel. 20 ms: one
 * 50 Hz period, two of the 100 Hz flicker; the chopping at 25 Hz is no harmonic of 50 Hz. make MAINS=60 gives
 * 50 ms (3 periods of 60 Hz, 6 of 120 Hz; also whole periods of 50 and 100 Hz). */
#ifndef MAINS
#define MAINS 50
#endif
#if MAINS == 60
#define CHOP_HALF_US 50000UL
#else
#define CHOP_HALF_US 20000UL
#endif
#define CHOP_HALF_NCONV (CHOP_HALF_US / SAMPLE_PERIOD_US)

/* Wait after a gain switch before integrating, microseconds: what the amplifier needs. The amplifier (hardware/frontend/frontend.cir,
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
#define MONITOR_CHANNEL 1
#ifndef MONITOR
#define MONITOR 0
#endif
#define ADS1115_ADDR 0x48    /* ADDR pin to GND */
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

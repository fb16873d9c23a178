/* Hardware layer of the detector board (see hw.h). Interrupt-driven UART, Timer1 clock, Timer0-paced ADC. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/pgmspace.h>
#include <avr/sleep.h>
#include <avr/wdt.h>

#include "config.h"
#include "hw.h"

volatile struct fw_probe fw_probe;

/* MCUSR is read and cleared before main (the watchdog stays on after a watchdog reset otherwise). */
static uint8_t reset_flags __attribute__((section(".noinit")));
void early_init(void) __attribute__((naked, used, section(".init3")));
void early_init(void)
{
    reset_flags = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

const char *hw_reset_cause(void)
{
    if (reset_flags & _BV(WDRF)) return "watchdog";
    if (reset_flags & _BV(BORF)) return "brownout";
    if (reset_flags & _BV(EXTRF)) return "external";
    return "power";
}

/* Sleep (idle mode: timers, UART and ADC keep running) until the next interrupt, unless cond already holds.
 * sei immediately before sleep: a pending interrupt is taken after the sleep instruction, so it wakes us. */
#define SLEEP_UNLESS(cond)                          \
    do {                                            \
        cli();                                      \
        if (!(cond)) {                              \
            sleep_enable();                         \
            sei();                                  \
            sleep_cpu();                            \
            sleep_disable();                        \
        }                                           \
        sei();                                      \
    } while (0)

/* --- UART ------------------------------------------------------------------------------------------------- */
#define RX_SIZE 64
#define TX_SIZE 128
static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail, rx_lost;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;

ISR(USART_RX_vect)
{
    uint8_t status = UCSR0A;
    uint8_t c = UDR0;
    uint8_t next = (rx_head + 1) & (RX_SIZE - 1);
    fw_probe.busy = 1;
    if (status & (_BV(FE0) | _BV(DOR0))) rx_lost = 1;
    if (next == rx_tail) {
        rx_lost = 1;
        return;
    }
    rx_buf[rx_head] = c;
    rx_head = next;
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= ~_BV(UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (tx_tail + 1) & (TX_SIZE - 1);
}

int16_t uart_getc(void)
{
    if (rx_head == rx_tail) return -1;
    uint8_t c = rx_buf[rx_tail];
    rx_tail = (rx_tail + 1) & (RX_SIZE - 1);
    return c;
}

uint8_t uart_rx_overflowed(void)
{
    uint8_t sreg = SREG;
    cli();
    uint8_t lost = rx_lost;
    rx_lost = 0;
    SREG = sreg;
    return lost;
}

void uart_putc(char c)
{
    uint8_t next = (tx_head + 1) & (TX_SIZE - 1);
    while (next == tx_tail) {
        wdt_reset();
        SLEEP_UNLESS(next != tx_tail);
    }
    tx_buf[tx_head] = (uint8_t)c;
    tx_head = next;
    UCSR0B |= _BV(UDRIE0);
}

void uart_puts(const char *s)
{
    while (*s) uart_putc(*s++);
}

void uart_puts_P(const char *s)
{
    char c;
    while ((c = (char)pgm_read_byte(s++))) uart_putc(c);
}

void uart_put_u64(uint64_t v)
{
    char d[21];
    uint8_t i = 0;
    do {
        d[i++] = (char)('0' + (uint8_t)(v % 10));
        v /= 10;
    } while (v);
    while (i) uart_putc(d[--i]);
}

void uart_put_fixed(uint64_t v, uint8_t decimals)
{
    uint64_t scale = 1;
    for (uint8_t i = 0; i < decimals; i++) scale *= 10;
    uart_put_u64(v / scale);
    if (!decimals) return;
    uart_putc('.');
    uint64_t frac = v % scale;
    for (uint8_t i = decimals; i; i--) {
        scale /= 10;
        uart_putc((char)('0' + (uint8_t)(frac / scale)));
        frac %= scale;
    }
}

void uart_put_seconds_us(uint64_t us)
{
    uart_put_u64(us / 1000000UL);
    uint32_t frac = (uint32_t)(us % 1000000UL);
    if (!frac) return;
    uart_putc('.');
    uint32_t scale = 100000UL;
    while (frac) {
        uart_putc((char)('0' + (uint8_t)(frac / scale)));
        frac %= scale;
        scale /= 10;
    }
}

void idle_until_input(void)
{
    cli();
    if (rx_head == rx_tail && tx_head == tx_tail) {
        fw_probe.busy = 0; /* nothing to do until a byte arrives: the harness may hold simulated time */
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
    sei();
}

/* --- clock: Timer1 free-running at clk/64 = 4 us per tick ---------------------------------------------------- */
static volatile uint32_t t1_overflows;

ISR(TIMER1_OVF_vect) { t1_overflows++; }
EMPTY_INTERRUPT(TIMER1_COMPB_vect); /* only wakes sleep_us */

static uint64_t clock_ticks(void)
{
    uint8_t sreg = SREG;
    cli();
    uint16_t t = TCNT1;
    uint32_t o = t1_overflows;
    if ((TIFR1 & _BV(TOV1)) && t < 0x8000) o++; /* overflowed, interrupt not yet served */
    SREG = sreg;
    return ((uint64_t)o << 16) | t;
}

uint64_t clock_us(void) { return clock_ticks() * 4; }

void sleep_us(uint32_t us)
{
    uint64_t target = clock_ticks() + (us + 3) / 4;
    TIMSK1 |= _BV(OCIE1B);
    for (;;) {
        wdt_reset();
        if (clock_ticks() >= target) break;
        OCR1B = (uint16_t)target; /* wakes at the target's phase; overflows wake every 262 ms in between */
        SLEEP_UNLESS(clock_ticks() >= target);
    }
    TIMSK1 &= ~_BV(OCIE1B);
}

/* --- pins --------------------------------------------------------------------------------------------------- */
void set_source(uint8_t on)
{
    if (on) SOURCE_PORT |= _BV(SOURCE_BIT);
    else SOURCE_PORT &= ~_BV(SOURCE_BIT);
    fw_probe.source = on ? 1 : 0;
}

void set_gain_index(uint8_t i)
{
    GAIN_PORT = (GAIN_PORT & ~GAIN_MASK) | (i & GAIN_MASK);
    fw_probe.gain = i;
}

void set_reference(uint8_t in_beam)
{
    if (in_beam) CHANGER_PORT |= _BV(CHANGER_BIT);
    else CHANGER_PORT &= ~_BV(CHANGER_BIT);
}

/* --- ADC integration: Timer0 CTC at 8 kHz starts a conversion every 125 us ------------------------------------ */
static volatile uint32_t adc_to_start, adc_to_finish;
static volatile int32_t adc_sum;
static volatile uint8_t adc_clip;

ISR(TIMER0_COMPA_vect)
{
    if (adc_to_start) {
        ADCSRA |= _BV(ADSC);
        if (--adc_to_start == 0) TCCR0B = 0;
    }
}

ISR(ADC_vect)
{
    uint16_t v = ADC;
    if (!adc_to_finish) return; /* the warm-up conversion */
    adc_sum += v;
    if (v >= CLIP_COUNT) adc_clip = 1;
    adc_to_finish--;
}

void repeat_led(uint8_t on)
{
    if (on) LED_PORT |= _BV(LED_BIT);
    else LED_PORT &= ~_BV(LED_BIT);
}

/* the ATmega's ADC on channel ch (Timer0 paces the conversions at 8 kHz) */
static int32_t integrate_avr(uint8_t ch, uint32_t nconv, uint8_t *clipped)
{
    ADMUX = _BV(REFS0) | ch;
    cli();
    adc_sum = 0;
    adc_clip = 0;
    adc_to_finish = nconv;
    adc_to_start = nconv - 1;
    TCNT0 = 0;
    TIFR0 = _BV(OCF0A);
    sei();
    ADCSRA |= _BV(ADSC);      /* the first conversion now, the others every sample period */
    if (nconv > 1) TCCR0B = _BV(CS01);
    while (adc_to_finish) {
        wdt_reset();
        SLEEP_UNLESS(adc_to_finish == 0);
    }
    TCCR0B = 0;
    if (ch != ADC_CHANNEL) ADMUX = _BV(REFS0) | ADC_CHANNEL;
    *clipped = adc_clip;
    return adc_sum;
}

#if ADC_ADS1115
#include "ads1115.h"

int32_t integrate(uint8_t channel, uint32_t nconv, uint8_t *clipped, uint8_t *fault)
{
    *fault = 0;
    if (channel != ADC_CHANNEL) /* the monitor on the ATmega's ADC over the same time */
        return integrate_avr(channel, nconv * (SAMPLE_PERIOD_US / AVR_PERIOD_US), clipped);
    return ads1115_integrate(nconv, clipped, fault);
}

uint8_t adc_present(void) { return ads1115_present(); }
#else
int32_t integrate(uint8_t channel, uint32_t nconv, uint8_t *clipped, uint8_t *fault)
{
    *fault = 0;
    return integrate_avr(channel, nconv, clipped);
}

uint8_t adc_present(void) { return 1; }
#endif

void hw_init(void)
{
    SOURCE_DDR |= _BV(SOURCE_BIT);
    GAIN_DDR |= GAIN_MASK;
    LED_DDR |= _BV(LED_BIT);
#if SAMPLE_CHANGER
    CHANGER_DDR |= _BV(CHANGER_BIT);
#endif
    set_source(1);
    set_gain_index(0);

    /* UART 115200 8N1, double speed: UBRR 16 gives 117647 baud (+2.1 %), as the Arduino core and bootloader */
    UBRR0H = 0;
    UBRR0L = 16;
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);

    TCCR1A = 0;
    TCCR1B = _BV(CS11) | _BV(CS10); /* clk/64 */
    TIMSK1 = _BV(TOIE1);

    TCCR0A = _BV(WGM01); /* CTC */
    OCR0A = (uint8_t)(AVR_PERIOD_US * 2 - 1); /* clk/8 = 2 MHz */
    TIMSK0 = _BV(OCIE0A);

    DIDR0 = _BV(ADC_CHANNEL) | _BV(MONITOR_CHANNEL);
    ADMUX = _BV(REFS0) | ADC_CHANNEL; /* AVcc reference */
    ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    ADCSRA |= _BV(ADSC); /* the first conversion after enabling takes 25 ADC clocks: do it now */
    while (ADCSRA & _BV(ADSC)) {
    }
#if ADC_ADS1115
    ads1115_init();
#endif
    wdt_enable(WDTO_2S);
}

/* The ADS1115 on the ATmega's TWI (SDA A4, SCL A5) at 400 kHz, polled; see ads1115.h. */
#include <avr/io.h>
#include <avr/wdt.h>
#include <util/delay.h>
#include <util/twi.h>

#include "ads1115.h"
#include "config.h"
#include "hw.h"

#define SLA_W ((ADS1115_ADDR << 1) | TW_WRITE)
#define SLA_R ((ADS1115_ADDR << 1) | TW_READ)

/* TWINT within a bound far beyond one byte at 400 kHz (22.5 us): about 5 ms of polling. The first 25 us are
 * waited out: a byte takes that long on the bus, and simavr 1.6 (the tests' emulation) leaves TWINT set until
 * its delayed status arrives, which polling at once would take for the end of the transfer. */
static uint8_t twi_wait(void)
{
    _delay_us(25);
    for (uint16_t i = 0; i < 16000; i++)
        if (TWCR & _BV(TWINT)) return 1;
    return 0;
}

static void twi_stop(void)
{
    TWCR = _BV(TWINT) | _BV(TWSTO) | _BV(TWEN);
    for (uint16_t i = 0; i < 16000 && (TWCR & _BV(TWSTO)); i++) {
    }
}

/* START (or repeated START) and the address byte; 1 when the slave acknowledged it. SLA+W acknowledged reads
 * 0x18 (TW_MT_SLA_ACK) on the ATmega; simavr 1.6 (Debian's, the tests' emulation) reports 0x28 (TW_MT_DATA_ACK)
 * there instead, a status a real TWI never gives after an address: both are taken as the acknowledge (a NACK is
 * 0x20, or 0x30 on simavr). */
static uint8_t twi_start(uint8_t sla)
{
    TWCR = _BV(TWINT) | _BV(TWSTA) | _BV(TWEN);
    if (!twi_wait() || (TW_STATUS != TW_START && TW_STATUS != TW_REP_START)) return 0;
    TWDR = sla;
    TWCR = _BV(TWINT) | _BV(TWEN);
    if (!twi_wait()) return 0;
    if (sla & 1) return TW_STATUS == TW_MR_SLA_ACK;
    return TW_STATUS == TW_MT_SLA_ACK || TW_STATUS == TW_MT_DATA_ACK;
}

static uint8_t twi_write(uint8_t b)
{
    TWDR = b;
    TWCR = _BV(TWINT) | _BV(TWEN);
    return twi_wait() && TW_STATUS == TW_MT_DATA_ACK;
}

static uint8_t twi_read(uint8_t ack, uint8_t *b)
{
    TWCR = _BV(TWINT) | _BV(TWEN) | (ack ? _BV(TWEA) : 0);
    if (!twi_wait()) return 0;
    *b = TWDR;
    return 1;
}

/* write a 16-bit register: pointer, then MSB, LSB */
static uint8_t write_reg(uint8_t reg, uint16_t v)
{
    uint8_t okay = twi_start(SLA_W) && twi_write(reg) && twi_write((uint8_t)(v >> 8)) && twi_write((uint8_t)v);
    twi_stop();
    return okay;
}

/* read a 16-bit register: a pointer write, then a read of MSB, LSB (big-endian) */
static uint8_t read_reg(uint8_t reg, uint16_t *v)
{
    uint8_t hi = 0, lo = 0;
    uint8_t okay = twi_start(SLA_W) && twi_write(reg);
    twi_stop();
    okay = okay && twi_start(SLA_R) && twi_read(1, &hi) && twi_read(0, &lo);
    twi_stop();
    *v = ((uint16_t)hi << 8) | lo;
    return okay;
}

void ads1115_init(void)
{
    TWSR = 0;                                  /* prescaler 1 */
    TWBR = (uint8_t)((F_CPU / 400000UL - 16) / 2); /* 400 kHz */
    TWCR = _BV(TWEN);
}

uint8_t ads1115_present(void)
{
    uint8_t okay = twi_start(SLA_W);
    twi_stop();
    return okay;
}

int32_t ads1115_integrate(uint32_t nconv, uint8_t *clipped, uint8_t *fault)
{
    int32_t sum = 0;
    *clipped = 0;
    *fault = 0;
    uint64_t slot = clock_us();
    for (uint32_t k = 0; k < nconv; k++, slot += SAMPLE_PERIOD_US) {
        wdt_reset();
        uint64_t now = clock_us();
        if (slot > now) sleep_us((uint32_t)(slot - now));
        if (!write_reg(ADS1115_REG_CONFIG, ADS1115_CONFIG_START)) {
            *fault = 1;
            return 0;
        }
        /* a conversion takes 1/860 s = 1163 us (+-10 % with the ADS1115's oscillator): read it 1400 us on */
        now = clock_us();
        if (slot + 1400 > now) sleep_us((uint32_t)(slot + 1400 - now));
        uint16_t cfg = 0, code = 0;
        uint8_t polls = 0;
        do {
            if (!read_reg(ADS1115_REG_CONFIG, &cfg) || ++polls > 20) { /* 20 polls: about 3 ms more */
                *fault = 1;
                return 0;
            }
        } while (!(cfg & ADS1115_OS));
        if (!read_reg(ADS1115_REG_CONVERSION, &code)) {
            *fault = 1;
            return 0;
        }
        int16_t v = (int16_t)code;
        if (v >= 32767 || v <= -32768) *clipped = 1;
        sum += v;
    }
    return sum;
}

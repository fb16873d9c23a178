/* The ADS1115 16-bit ADC on I2C (build option ADC=ads1115): TWI master without interrupts, every wait bounded. */
#ifndef DETECTOR_ADS1115_H
#define DETECTOR_ADS1115_H

#include <stdint.h>

/* Config register (datasheet SBAS444, table 8): OS = 1 (start a single conversion), MUX = 000 (AIN0 - AIN1),
 * PGA = 001 (+-4.096 V, 125 uV a count), MODE = 1 (single shot), DR = 111 (860 samples/s), comparator off
 * (COMP_QUE = 11). */
#define ADS1115_REG_CONVERSION 0x00
#define ADS1115_REG_CONFIG 0x01
#define ADS1115_CONFIG_START 0x83E3u
#define ADS1115_OS 0x8000u

void ads1115_init(void);
uint8_t ads1115_present(void);  /* the device acknowledges its address */
/* sum of nconv single-shot conversions of AIN0 - AIN1, one every SAMPLE_PERIOD_US; *clipped when one read the
 * code's limits; *fault when the device did not answer (the sum is then 0) */
int32_t ads1115_integrate(uint32_t nconv, uint8_t *clipped, uint8_t *fault);

#endif

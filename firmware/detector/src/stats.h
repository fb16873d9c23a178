/* Exact running statistics of a reading's repeats (no storage: the values are sent as they are measured). */
#ifndef DETECTOR_STATS_H
#define DETECTOR_STATS_H

#include <stdint.h>

struct stats {
    uint16_t n;
    int32_t x0;     /* the first value: deviations from it keep the sums small */
    int64_t s1;      /* sum of (x - x0) */
    uint64_t s2;     /* sum of (x - x0)^2 */
    int64_t sum;     /* sum of x */
};

void stats_init(struct stats *s);
void stats_add(struct stats *s, int32_t x);  /* chopped readings can be negative */
int64_t stats_mean_milli(const struct stats *s);   /* round(1000 * mean), halves away from zero */
uint64_t stats_std_milli(const struct stats *s);   /* round(1000 * sample std), 0 for n < 2 */

#endif

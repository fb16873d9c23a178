/* Exact mean and sample standard deviation in integer arithmetic (avr-gcc's double is 32 bits: too coarse for
 * the 3 decimals the driver checks against the values). Values are at most 1023 * 80000 < 2^27 in size (negative ones from a chopped reading), n <= 1000:
 * V = n * S2 - S1^2 < 2^75 needs 128-bit arithmetic, written here on pairs of 64-bit words. */
#include "stats.h"

typedef struct {
    uint64_t hi, lo;
} u128;

static u128 mul64(uint64_t a, uint64_t b)
{
    uint64_t a0 = (uint32_t)a, a1 = a >> 32, b0 = (uint32_t)b, b1 = b >> 32;
    uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0, p11 = a1 * b1;
    uint64_t mid = (p00 >> 32) + (uint32_t)p01 + (uint32_t)p10;
    u128 r;
    r.lo = (mid << 32) | (uint32_t)p00;
    r.hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
    return r;
}

static u128 sub(u128 a, u128 b)
{
    u128 r;
    r.lo = a.lo - b.lo;
    r.hi = a.hi - b.hi - (a.lo < b.lo);
    return r;
}

static u128 add(u128 a, u128 b)
{
    u128 r;
    r.lo = a.lo + b.lo;
    r.hi = a.hi + b.hi + (r.lo < a.lo);
    return r;
}

static int ge(u128 a, u128 b) { return a.hi > b.hi || (a.hi == b.hi && a.lo >= b.lo); }

static u128 shr(u128 a, uint8_t k)
{
    u128 r;
    if (k >= 64) {
        r.lo = a.hi >> (k - 64);
        r.hi = 0;
    } else if (k) {
        r.lo = (a.lo >> k) | (a.hi << (64 - k));
        r.hi = a.hi >> k;
    } else {
        r = a;
    }
    return r;
}

/* a / d for a 32-bit d: long division on 32-bit limbs */
static u128 divu32(u128 a, uint32_t d)
{
    uint32_t limb[4] = {(uint32_t)(a.hi >> 32), (uint32_t)a.hi, (uint32_t)(a.lo >> 32), (uint32_t)a.lo};
    uint64_t rem = 0;
    for (uint8_t i = 0; i < 4; i++) {
        uint64_t cur = (rem << 32) | limb[i];
        limb[i] = (uint32_t)(cur / d);
        rem = cur % d;
    }
    u128 r;
    r.hi = ((uint64_t)limb[0] << 32) | limb[1];
    r.lo = ((uint64_t)limb[2] << 32) | limb[3];
    return r;
}

/* floor(sqrt(a)), digit by digit; the result fits 64 bits */
static uint64_t isqrt(u128 a, int *exact_above_half)
{
    u128 res = {0, 0}, bit = {1ULL << 62, 0};
    while (!ge(a, bit) && (bit.hi | bit.lo)) bit = shr(bit, 2);
    while (bit.hi | bit.lo) {
        u128 t = add(res, bit);
        if (ge(a, t)) {
            a = sub(a, t);
            res = add(shr(res, 1), bit);
        } else {
            res = shr(res, 1);
        }
        bit = shr(bit, 2);
    }
    /* a now holds the remainder v - r^2; sqrt(v) >= r + 1/2 iff remainder > r */
    *exact_above_half = (a.hi != 0) || (a.lo > res.lo);
    return res.lo;
}

void stats_init(struct stats *s)
{
    s->n = 0;
    s->x0 = 0;
    s->s1 = 0;
    s->s2 = 0;
    s->sum = 0;
}

void stats_add(struct stats *s, int32_t x)
{
    if (s->n == 0) s->x0 = x;
    int64_t d = (int64_t)x - (int64_t)s->x0;
    s->n++;
    s->sum += x;
    s->s1 += d;
    s->s2 += (uint64_t)(d * d);
}

int64_t stats_mean_milli(const struct stats *s)
{
    if (!s->n) return 0;
    int64_t half = s->n / 2;
    return s->sum >= 0 ? (s->sum * 1000 + half) / s->n : -((-s->sum * 1000 + half) / s->n);
}

uint64_t stats_std_milli(const struct stats *s)
{
    if (s->n < 2) return 0;
    uint64_t a1 = (uint64_t)(s->s1 < 0 ? -s->s1 : s->s1);
    u128 v = sub(mul64(s->s2, s->n), mul64(a1, a1)); /* n S2 - S1^2 >= 0 */
    /* v * 10^6 / (n (n - 1)): multiply in two steps of 1000 (v < 2^75, the product < 2^95) */
    u128 hi = mul64(v.hi, 1000000ULL), lo = mul64(v.lo, 1000000ULL);
    u128 w = {hi.lo + lo.hi, lo.lo};
    w = divu32(w, (uint32_t)s->n * (uint32_t)(s->n - 1));
    int up;
    uint64_t r = isqrt(w, &up);
    return r + (up ? 1 : 0);
}

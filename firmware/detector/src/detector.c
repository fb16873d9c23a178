/* gonio-brdf detector board firmware: the detector side of docs/serial-protocol.md (motion=none).
 *
 * One command a line; every command gets zero or more data lines, then exactly one final line, ok or error:N.
 * The only unsolicited line is the start-up banner (BOOT ...). See docs/serial-protocol.md, "The detector board
 * firmware", for what this board does differently from the simulator (10-bit ADC summed over a repeat,
 * integration times in steps of 125 us, the order of the READ fields). */
#include <avr/pgmspace.h>
#include <avr/wdt.h>
#include <string.h>

#include "config.h"
#include "hw.h"
#include "stats.h"

#define E_UNKNOWN 1
#define E_ARGUMENT 2
#define E_LINE_TOO_LONG 4
#define E_NOT_AVAILABLE 10
#define E_ADC 12 /* the ADC does not answer (ADC=ads1115: no acknowledge from the ADS1115 at 0x48) */

static const uint32_t gains[] = {GAIN_LIST};
#define N_GAINS (sizeof(gains) / sizeof(gains[0]))
typedef char gains_fit_the_multiplexer[(N_GAINS >= 1 && N_GAINS <= 8) ? 1 : -1];

static uint32_t nconv = DEFAULT_NCONV;   /* conversions per repeat */
static uint8_t gain_index;
static uint32_t settle_due_us;          /* the wait still owed for a source or gain switch before integrating */
static uint8_t source_enabled = 1;      /* SOURCE ON/OFF: the pin's state between readings and during READ */
static uint8_t chop;                    /* CHOP ON: readings are on-minus-off sums of chopped halves */
static uint32_t source_settle_us = SOURCE_SETTLE_US; /* SETTLE <s> */

static void owe_settle(uint32_t us)
{
    if (us > settle_due_us) settle_due_us = us;
}

/* switch the source pin (when it changes) and owe its settle time */
static void switch_source(uint8_t on)
{
    if (fw_probe.source != on) {
        set_source(on);
        owe_settle(source_settle_us);
    }
}

static void settle(void)
{
    if (settle_due_us) sleep_us(settle_due_us);
    settle_due_us = 0;
}

/* conversions per repeat (the source's on-time when chopped: a whole number of chopping halves) */
static uint32_t repeat_nconv(void)
{
    if (!chop) return nconv;
    uint32_t halves = (nconv + CHOP_HALF_NCONV / 2) / CHOP_HALF_NCONV;
    return (halves ? halves : 1) * CHOP_HALF_NCONV;
}

static void upcase(char *p)
{
    for (; p && *p; p++)
        if (*p >= 'a' && *p <= 'z') *p -= 'a' - 'A';
}

/* --- replies -------------------------------------------------------------------------------------------------- */
static void ok(void) { uart_puts_P(PSTR("ok\n")); }

static void error(uint8_t code)
{
    uart_puts_P(PSTR("error:"));
    uart_put_u64(code);
    uart_putc('\n');
}

static void field_u64(const char *key_P, uint64_t v)
{
    uart_puts_P(key_P);
    uart_put_u64(v);
}

static void put_i64_milli(int64_t v)
{
    if (v < 0) {
        uart_putc('-');
        v = -v;
    }
    uart_put_fixed((uint64_t)v, 3);
}

static void put_i32(int32_t v)
{
    if (v < 0) {
        uart_putc('-');
        v = -v;
    }
    uart_put_u64((uint64_t)v);
}

static void put_gains(void)
{
    for (uint8_t i = 0; i < N_GAINS; i++) {
        if (i) uart_putc(',');
        uart_put_u64(gains[i]);
    }
}

/* --- numbers -------------------------------------------------------------------------------------------------- */
/* Parse a decimal number ([+]digits[.digits][e[+-]digits], as Python prints it) and return it times 10^scale,
 * rounded, in *out. 0 on a malformed or negative number or an overflow. */
static uint8_t parse_scaled(const char *s, int8_t scale, uint64_t *out)
{
    uint64_t m = 0;
    int16_t exp10 = scale;
    uint8_t digits = 0, any = 0;
    if (*s == '+') s++;
    for (; *s >= '0' && *s <= '9'; s++, any = 1) {
        if (digits < 18) {
            m = m * 10 + (uint8_t)(*s - '0');
            if (m) digits++;
        } else {
            exp10++;
        }
    }
    if (*s == '.') {
        for (s++; *s >= '0' && *s <= '9'; s++, any = 1) {
            if (digits < 18) {
                m = m * 10 + (uint8_t)(*s - '0');
                if (m) digits++;
                exp10--;
            }
        }
    }
    if (!any) return 0;
    if (*s == 'e' || *s == 'E') {
        s++;
        int8_t sign = 1;
        if (*s == '+' || *s == '-') sign = (*s++ == '-') ? -1 : 1;
        int16_t e = 0;
        uint8_t edigits = 0;
        for (; *s >= '0' && *s <= '9'; s++, edigits++)
            if (e < 1000) e = e * 10 + (*s - '0');
        if (!edigits) return 0;
        exp10 += sign * e;
    }
    if (*s) return 0;
    if (m == 0) {
        *out = 0;
        return 1;
    }
    for (; exp10 > 0; exp10--) {
        if (m > UINT64_MAX / 10) return 0;
        m *= 10;
    }
    for (; exp10 < 0; exp10++) {
        if (exp10 == -1) {
            m = (m + 5) / 10;
        } else {
            m /= 10;
            if (!m) break;
        }
    }
    *out = m;
    return 1;
}

/* 1..MAX_REPEATS, or 0 */
static uint16_t parse_repeats(const char *s)
{
    uint32_t v = 0;
    if (*s == '+') s++;
    if (!*s) return 0;
    for (; *s; s++) {
        if (*s < '0' || *s > '9') return 0;
        v = v * 10 + (uint8_t)(*s - '0');
        if (v > MAX_REPEATS) return 0;
    }
    return (uint16_t)v;
}

/* --- commands ------------------------------------------------------------------------------------------------- */
static void cmd_id(void)
{
    uart_puts_P(PSTR("ID name=" FW_NAME " version=" FW_VERSION " motion=none axes=- detector=photodiode\n"));
    ok();
}

static void cmd_status(void)
{
    uart_puts_P(PSTR("STATUS state=Idle t="));
    uart_put_fixed(clock_us(), 6);
    uart_puts_P(PSTR(" alarm=0\n"));
    ok();
}

static void cmd_time(void)
{
    uart_puts_P(PSTR("TIME t="));
    uart_put_fixed(clock_us(), 6);
    uart_putc('\n');
    ok();
}

static void cmd_help(void)
{
    uart_puts_P(PSTR("HELP CHOP CHOP? DARK DETECTOR? DWELL GAIN GAIN? HELP ID? INT INT? READ RESET"));
    if (SAMPLE_CHANGER) uart_puts_P(PSTR(" SAMPLE SAMPLE?"));
    uart_puts_P(PSTR(" SETTLE SETTLE? SOURCE SOURCE? STATUS? STOP TIME?\n"));
    ok();
}

static void cmd_source(char *arg)
{
    upcase(arg);
    if (arg && strcmp_P(arg, PSTR("ON")) == 0) source_enabled = 1;
    else if (arg && strcmp_P(arg, PSTR("OFF")) == 0) source_enabled = 0;
    else {
        error(E_ARGUMENT);
        return;
    }
    switch_source(source_enabled);
    ok();
}

static void cmd_source_q(void)
{
    uart_puts_P(source_enabled ? PSTR("SOURCE source=ON\n") : PSTR("SOURCE source=OFF\n"));
    ok();
}

static uint8_t reference_in_beam;

static void cmd_sample(const char *arg)
{
    uint8_t ref;
    if (arg && strcmp_P(arg, PSTR("REF")) == 0) ref = 1;
    else if (arg && strcmp_P(arg, PSTR("TARGET")) == 0) ref = 0;
    else {
        error(E_ARGUMENT);
        return;
    }
    if (ref != reference_in_beam) {
        set_reference(ref);
        reference_in_beam = ref;
        sleep_us(CHANGER_SETTLE_MS * 1000UL);
    }
    ok();
}

static void cmd_sample_q(void)
{
    uart_puts_P(reference_in_beam ? PSTR("SAMPLE sample=REF\n") : PSTR("SAMPLE sample=TARGET\n"));
    ok();
}

static void cmd_chop(char *arg)
{
    upcase(arg);
    if (arg && strcmp_P(arg, PSTR("ON")) == 0) chop = 1;
    else if (arg && strcmp_P(arg, PSTR("OFF")) == 0) chop = 0;
    else {
        error(E_ARGUMENT);
        return;
    }
    ok();
}

static void cmd_chop_q(void)
{
    uart_puts_P(chop ? PSTR("CHOP chop=ON half=") : PSTR("CHOP chop=OFF half="));
    uart_put_seconds_us(CHOP_HALF_US);
    uart_putc('\n');
    ok();
}

static void cmd_settle(const char *arg)
{
    uint64_t us;
    if (!arg || !parse_scaled(arg, 6, &us) || us > MAX_SETTLE_US) {
        error(E_ARGUMENT);
        return;
    }
    source_settle_us = (uint32_t)us;
    ok();
}

static void cmd_settle_q(void)
{
    uart_puts_P(PSTR("SETTLE source="));
    uart_put_seconds_us(source_settle_us);
    uart_puts_P(PSTR(" gain="));
    uart_put_seconds_us(GAIN_SETTLE_US);
    uart_putc('\n');
    ok();
}

static void cmd_detector(void)
{
    uint32_t c = repeat_nconv();
    field_u64(PSTR("DETECTOR type=photodiode channels=1 bits="), ADC_BITS);
    field_u64(PSTR(" gain="), gains[gain_index]);
    field_u64(PSTR(" saturation="), (uint64_t)ADC_FULL * c);
    uart_puts_P(PSTR(" t_int="));
    uart_put_seconds_us((uint64_t)c * SAMPLE_PERIOD_US);
    uart_puts_P(PSTR(" gains="));
    put_gains();
    field_u64(PSTR(" conversions="), c);
    uart_puts_P(PSTR(" amplifier=dc"));
    uart_puts_P(chop ? PSTR(" chop=ON") : PSTR(" chop=OFF"));
    field_u64(PSTR(" clip="), (uint64_t)CLIP_COUNT);
    uart_putc('\n');
    ok();
}

static void cmd_int(const char *arg)
{
    uint64_t ns;
    if (!arg || !parse_scaled(arg, 9, &ns) || ns < MIN_INT_NS || ns > MAX_INT_NS) {
        error(E_ARGUMENT);
        return;
    }
    uint64_t period_ns = SAMPLE_PERIOD_US * 1000;
    uint64_t k = (ns + period_ns / 2) / period_ns;
    nconv = k < 1 ? 1 : (k > MAX_NCONV ? MAX_NCONV : (uint32_t)k);
    ok();
}

static void cmd_int_q(void)
{
    uart_puts_P(PSTR("INT t_int="));
    uart_put_seconds_us((uint64_t)repeat_nconv() * SAMPLE_PERIOD_US);
    uart_putc('\n');
    ok();
}

static void cmd_gain(const char *arg)
{
    uint64_t micro; /* the gain times 10^6 */
    if (!arg || !parse_scaled(arg, 6, &micro)) {
        error(E_ARGUMENT);
        return;
    }
    for (uint8_t i = 0; i < N_GAINS; i++) {
        uint64_t g = (uint64_t)gains[i] * 1000000ULL;
        uint64_t diff = micro > g ? micro - g : g - micro;
        if (diff <= gains[i]) { /* within 1e-6 relative */
            if (i != gain_index) owe_settle(GAIN_SETTLE_US);
            gain_index = i;
            set_gain_index(i);
            ok();
            return;
        }
    }
    error(E_ARGUMENT);
}

static void cmd_gain_q(void)
{
    field_u64(PSTR("GAIN gain="), gains[gain_index]);
    uart_putc('\n');
    ok();
}

static void cmd_dwell(const char *arg)
{
    uint64_t us;
    if (!arg || !parse_scaled(arg, 6, &us) || us > 3600000000ULL) {
        error(E_ARGUMENT);
        return;
    }
    sleep_us((uint32_t)us);
    ok();
}

/* One repeat: c conversions with the source on (READ) or off (DARK); chopped, the sum of the "on" halves minus
 * the "off" halves (DARK keeps the source off in both: it reads what the chopping leaves of the room light). */
static int32_t one_repeat(uint8_t source_on, uint32_t c, uint8_t *clipped, uint8_t *fault)
{
    if (!chop) return integrate(ADC_CHANNEL, c, clipped, fault);
    int32_t v = 0;
    *clipped = 0;
    for (uint32_t done = 0; done < c && !*fault; done += CHOP_HALF_NCONV) {
        uint8_t clip_on, clip_off;
        switch_source(source_on);
        owe_settle(source_settle_us);
        settle();
        v += integrate(ADC_CHANNEL, CHOP_HALF_NCONV, &clip_on, fault);
        if (*fault) break;
        switch_source(0);
        owe_settle(source_settle_us); /* the same wait in both halves, whichever the source does */
        settle();
        v -= integrate(ADC_CHANNEL, CHOP_HALF_NCONV, &clip_off, fault);
        *clipped |= clip_on | clip_off;
    }
    return v;
}

/* READ / DARK: the values are sent while they are measured (a reading of 1000 repeats does not fit in RAM), so
 * sat, mean and std follow them on the same line. */
static void cmd_read(const char *arg, uint8_t is_read)
{
    uint8_t source_on = is_read && source_enabled; /* READ with the source switched off reads dark */
    uint16_t n = arg ? parse_repeats(arg) : DEFAULT_REPEATS;
    if (!n) {
        error(E_ARGUMENT);
        return;
    }
    if (!adc_present()) {
        error(E_ADC);
        return;
    }
    uint32_t c = repeat_nconv();
    if (!chop) {
        switch_source(source_on);
        settle();
    }
    uart_puts_P(is_read ? PSTR("READ n=") : PSTR("DARK n="));
    uart_put_u64(n);
    uart_puts_P(PSTR(" t_int="));
    uart_put_seconds_us((uint64_t)c * SAMPLE_PERIOD_US);
    field_u64(PSTR(" gain="), gains[gain_index]);
    uart_puts_P(PSTR(" values="));
    struct stats st;
    stats_init(&st);
    uint16_t sat = 0;
    uint8_t fault = 0;
    fw_probe.n = n;
    fw_probe.nconv = c;
    fw_probe.chop = chop;
    for (uint16_t k = 0; k < n && !fault; k++) {
        uint8_t clipped;
        fw_probe.first = (k == 0);
        repeat_led(1); /* the harness sets the amplifier's output at this edge */
        int32_t v = one_repeat(source_on, c, &clipped, &fault);
        repeat_led(0);
        sat += clipped;
        stats_add(&st, v);
        if (k) uart_putc(',');
        put_i32(v);
    }
    fw_probe.first = 0;
    if (fault) { /* the ADS1115 stopped answering mid-reading: end the line, then the error */
        uart_putc('\n');
        switch_source(source_enabled);
        error(E_ADC);
        return;
    }
    field_u64(PSTR(" sat="), sat);
    uart_puts_P(PSTR(" mean="));
    put_i64_milli(stats_mean_milli(&st));
    uart_puts_P(PSTR(" std="));
    uart_put_fixed(stats_std_milli(&st), 3);
#if MONITOR
    { /* the monitor photodiode, source as for the reading, over one repeat's integration time */
        uint8_t clipped, f;
        switch_source(source_on);
        settle();
        int32_t m = integrate(MONITOR_CHANNEL, c, &clipped, &f);
        field_u64(PSTR(" monitor="), (uint64_t)(m < 0 ? 0 : m));
    }
#endif
    uart_putc('\n');
    switch_source(source_enabled); /* back to SOURCE's state (on, unless switched off) */
    ok();
}

static uint8_t is(const char *word, const char *name_P) { return strcmp_P(word, name_P) == 0; }

static void handle(char *line)
{
    char *argv[3] = {0, 0, 0};
    uint8_t argc = 0;
    for (char *p = line; *p;) {
        while (*p == ' ' || *p == '\t') *p++ = 0;
        if (!*p) break;
        if (argc == 3) {
            error(E_ARGUMENT);
            return;
        }
        argv[argc++] = p;
        while (*p && *p != ' ' && *p != '\t') p++;
    }
    if (!argc) return; /* blank line: no reply */
    for (char *p = argv[0]; *p; p++)
        if (*p >= 'a' && *p <= 'z') *p -= 'a' - 'A';
    const char *arg = argv[1];
    uint8_t one = argc <= 2, none = argc == 1;
    char *w = argv[0];
    if (is(w, PSTR("ID?"))) none ? cmd_id() : error(E_ARGUMENT);
    else if (is(w, PSTR("STATUS?")) || is(w, PSTR("?"))) none ? cmd_status() : error(E_ARGUMENT);
    else if (is(w, PSTR("TIME?"))) none ? cmd_time() : error(E_ARGUMENT);
    else if (is(w, PSTR("HELP"))) cmd_help();
    else if (is(w, PSTR("READ"))) one ? cmd_read(arg, 1) : error(E_ARGUMENT);
    else if (is(w, PSTR("DARK"))) one ? cmd_read(arg, 0) : error(E_ARGUMENT);
    else if (is(w, PSTR("DETECTOR?"))) none ? cmd_detector() : error(E_ARGUMENT);
    else if (is(w, PSTR("INT"))) one ? cmd_int(arg) : error(E_ARGUMENT);
    else if (is(w, PSTR("INT?"))) none ? cmd_int_q() : error(E_ARGUMENT);
    else if (is(w, PSTR("GAIN"))) one ? cmd_gain(arg) : error(E_ARGUMENT);
    else if (is(w, PSTR("GAIN?"))) none ? cmd_gain_q() : error(E_ARGUMENT);
    else if (is(w, PSTR("DWELL"))) one ? cmd_dwell(arg) : error(E_ARGUMENT);
    else if (is(w, PSTR("SOURCE"))) one ? cmd_source(argv[1]) : error(E_ARGUMENT);
    else if (is(w, PSTR("SOURCE?"))) none ? cmd_source_q() : error(E_ARGUMENT);
    else if (is(w, PSTR("CHOP"))) one ? cmd_chop(argv[1]) : error(E_ARGUMENT);
    else if (is(w, PSTR("CHOP?"))) none ? cmd_chop_q() : error(E_ARGUMENT);
    else if (is(w, PSTR("SETTLE"))) one ? cmd_settle(arg) : error(E_ARGUMENT);
    else if (is(w, PSTR("SETTLE?"))) none ? cmd_settle_q() : error(E_ARGUMENT);
    else if (is(w, PSTR("STOP")) || is(w, PSTR("RESET"))) ok(); /* no axes, no alarms */
    else if (SAMPLE_CHANGER && is(w, PSTR("SAMPLE"))) {
        if (arg)
            for (char *p = (char *)arg; *p; p++)
                if (*p >= 'a' && *p <= 'z') *p -= 'a' - 'A';
        one ? cmd_sample(arg) : error(E_ARGUMENT);
    } else if (SAMPLE_CHANGER && is(w, PSTR("SAMPLE?"))) none ? cmd_sample_q() : error(E_ARGUMENT);
    else if (is(w, PSTR("MOVE")) || is(w, PSTR("HOME")) || is(w, PSTR("SAMPLE")) || is(w, PSTR("SAMPLE?")))
        error(E_NOT_AVAILABLE);
    else error(E_UNKNOWN);
}

/* --- line assembly ---------------------------------------------------------------------------------------------- */
static char line[MAX_LINE + 1];

int main(void)
{
    hw_init();
    uart_puts_P(PSTR("BOOT name=" FW_NAME " version=" FW_VERSION " reset="));
    uart_puts(hw_reset_cause());
    uart_putc('\n');
    uint16_t len = 0;
    uint8_t too_long = 0, garbage = 0;
    for (;;) {
        wdt_reset();
        int16_t c = uart_getc();
        if (uart_rx_overflowed()) garbage = 1; /* a byte of this line was lost */
        if (c < 0) {
            idle_until_input();
            continue;
        }
        if (c == '\n' || c == '\r') {
            line[len] = 0;
            if (too_long) error(E_LINE_TOO_LONG);
            else if (garbage) error(E_UNKNOWN);
            else handle(line);
            len = 0;
            too_long = garbage = 0;
        } else if (too_long) {
            /* discard up to the end of the line */
        } else if (len >= MAX_LINE) {
            too_long = 1;
        } else {
            if ((c < 0x20 && c != '\t') || c > 0x7e) garbage = 1;
            line[len++] = (char)c;
        }
    }
}

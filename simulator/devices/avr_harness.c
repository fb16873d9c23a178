/* avr_harness: runs the detector board's firmware (firmware/detector) on an emulated ATmega328P (simavr).
 *
 * Build (tests and gonio-sim do it at run time, simulator/devices/firmware.py):
 *   gcc -O2 -o avr_harness avr_harness.c -I/usr/include/simavr -lsimavr -lsimavrparts -lutil
 * Run:
 *   avr_harness [--dither LSB] [--seed N] [--no-ads1115] firmware.elf
 *
 * UART0 is a pseudo-terminal of its own (so that several harnesses can run at once): the first line on stdout is
 * "PTY <path>". stdin/stdout are a line-oriented control channel:
 *
 *   out  PTY <path> vref_mv=5000 full=1023 ads1115=0x48
 *                                            the pty; the ADC reads floor(full * mV / vref_mv), clipped at full;
 *                                            an ADS1115 answers on I2C at 0x48 (firmware built with ADC=ads1115)
 *   out  PIN gsel=<0..7> source=<0|1> reference=<0|1> t=<s>
 *                                            the gain-select pins PB0..PB2, the source pin PD7 and the sample
 *                                            changer's pin PD6, at start and on every change
 *   out  SYNC first=<0|1> n=<n> nconv=<c> gsel=<g> source=<s> chop=<0|1> t=<s>
 *                                            (sync mode) a repeat starts (the LED pin PB5 rises): the emulation
 *                                            waits for ADC <mV> (the amplifier's output for this repeat); chop=1:
 *                                            the firmware switches the source within the repeat (send DARKADC)
 *   out  TIME t=<s>                          reply to TIME?: emulated seconds since start
 *   out  BYE <reason>                        the harness stops
 *   in   ADC <mV> [<mV> ...]                 the voltage on ADC0 (A0), millivolts (to 0.1 mV; 0..6553 mV); in sync
 *                                            mode further values are those of the reading's next repeats, set at
 *                                            their LED edges without a SYNC (one round trip a reading)
 *   in   DARKADC <mV> [<mV> ...]             the amplifier's output while the source pin is low, for this repeat
 *                                            and the next ones (as ADC's list; send it before ADC). Without it, or
 *                                            after a new SYNC, the output is ADC's whatever the source pin
 *   in   FLICKER <mV> <hz>                   room light's flicker: amp * sin(2 pi hz t) added to the amplifier's
 *                                            output at every conversion (t: emulated time); FLICKER 0 0: none
 *   in   MON <mV>                            the voltage on ADC1 (A1): the monitor photodiode's amplifier, while
 *                                            the source pin is high (it sees the source only; 0 V while low)
 *   in   AIN1 <mV>                           the ADS1115's AIN1: the amplifier's reference (its AIN0 is the output)
 *   in   ADS1115 0|1                         the ADS1115 absent (never acknowledges: a missing or broken device)
 *                                            or present (the default unless --no-ads1115)
 *   in   DITHER <lsb>                        Gaussian noise added to every conversion, rms in ADC counts (the
 *                                            ATmega's, or the ADS1115's codes)
 *   in   SYNC 0|1                            off / on: wait for ADC at every repeat
 *   in   UNTIL <s>                           emulated time runs on to at least <s> (the board idles meanwhile;
 *                                            bytes from the host are delivered from then on)
 *   in   TIME?                               see above
 *   in   RESET                               external reset (reset button, or DTR on port open)
 *   in   FREEZE 0|1                          1: the board stops executing (a hung board); 0: it runs again
 *   in   NOISE <hex>                         bytes sent to the host as if by line noise on the board's TX line
 *   in   UNPLUG                              close the pty: the host's port vanishes as with a pulled cable
 *   in   QUIT                                (or end of input) stop
 *
 * Simulated time: the emulated core runs as fast as the host allows while the firmware works (a command, a
 * reading, bytes to send); while it sleeps waiting for input (its probe's busy flag is clear) time is held, so
 * emulated time only advances with work and with UNTIL, like gonio-sim's fast time (time_scale = 0). The sleep
 * callback never waits for wall time.
 *
 * The ADS1115 (TI SBAS444): a slave at 0x48 on the TWI (simavr's i2c irqs, as simavr's parts/i2c_eeprom). A write
 * sets the pointer register (first byte) and then writes the register it points to, MSB first (config 0x01, the
 * thresholds 0x02/0x03; the conversion register 0x00 is read-only); a read returns the pointed register, MSB first.
 * Config: OS (write 1: start a single conversion; read 0 while converting), MUX (AINp - AINn of the datasheet's
 * table), PGA (+-6.144 .. +-0.256 V), MODE (1 single shot, 0 continuous), DR (8 .. 860 samples/s); power-up value
 * 0x8583. A conversion takes 1/DR s and reads the mean input over that time, rounded to the LSB (FS / 32768),
 * clipped to -32768..32767 (16-bit two's complement).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <pty.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include <avr_adc.h>
#include <avr_ioport.h>
#include <avr_twi.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_io.h>

DEFINE_FIFO(uint16_t, uart_fifo); /* the accessors of the UART's receive FIFO (declared by avr_uart.h) */

#define FREQ 16000000UL
#define VREF_UNITS 50000U /* AVcc = 5 V in units of 0.1 mV (simavr's ADC inputs are 16-bit values) */
#define IN_SIZE 4096
#define CTRL_SIZE 16384
#define MAX_QUEUE 1000 /* the protocol's most repeats */

static avr_t *avr;
static avr_uart_t *uart;
static uint16_t probe_addr;
static int master = -1, slave_keep = -1, quit_flag;
static int sync_mode, waiting_sync, frozen, pins_dirty, last_gsel = -1, last_source = -1, last_reference = -1;
static double adc_mv, dither_lsb, flicker_mv, flicker_hz, mon_mv, ain1_mv;
static double dark_mv;          /* the output while the source pin is low (have_dark) */
static int have_dark;
static double queue_dark[MAX_QUEUE];
static int dark_len, dark_pos;
static uint64_t rng_state = 0x9e3779b97f4a7c15ULL, until_cycle;
static uint8_t inbuf[IN_SIZE];
static size_t in_len;
static double queue_mv[MAX_QUEUE];
static int queue_len, queue_pos;
static char ctrl[CTRL_SIZE];
static size_t ctrl_len;

static void say(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vfprintf(stdout, fmt, ap);
    va_end(ap);
    fputc('\n', stdout);
    fflush(stdout);
}

static void logger(avr_t *a, const int level, const char *fmt, va_list ap)
{
    (void)a;
    if (level <= LOG_ERROR) vfprintf(stderr, fmt, ap); /* simavr's warnings (e.g. about OCR0A written before
                                                          the timer's mode) are not the firmware's */
}

static double seconds(void) { return (double)avr->cycle / FREQ; }

/* --- randomness for the dither: xorshift64*, Box-Muller ------------------------------------------------------- */
static double uniform(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return ((rng_state * 2685821657736338717ULL) >> 11) * (1.0 / 9007199254740992.0);
}

static double gauss(void)
{
    double u = uniform(), v = uniform();
    if (u < 1e-300) u = 1e-300;
    return sqrt(-2.0 * log(u)) * cos(2.0 * M_PI * v);
}

/* --- the firmware's probe (struct fw_probe in firmware/detector/src/hw.h) ---------------------------------------- */
static uint8_t probe8(int off) { return avr->data[probe_addr + off]; }
static uint32_t probe_n(void) { return probe8(4) | (probe8(5) << 8); }
static uint32_t probe_nconv(void)
{
    return probe8(6) | (probe8(7) << 8) | ((uint32_t)probe8(8) << 16) | ((uint32_t)probe8(9) << 24);
}

static int gsel(void) { return avr->data[0x25] & 0x07; }           /* PORTB */
static int chop_flag(void) { return probe8(10); }
static int source(void) { return (avr->data[0x2B] >> 7) & 1; }     /* PORTD */
static int reference(void) { return (avr->data[0x2B] >> 6) & 1; }

/* the amplifier's output at time t (s): the source pin chooses the lit or the dark level, room light flickers */
static double tia_mv(double t)
{
    double mv = (have_dark && !source()) ? dark_mv : adc_mv;
    if (flicker_mv != 0 && flicker_hz > 0) mv += flicker_mv * sin(2.0 * M_PI * flicker_hz * t);
    return mv;
}

/* its mean over [t0, t1] (the flicker's sine integrated) */
static double tia_mean_mv(double t0, double t1)
{
    double mv = (have_dark && !source()) ? dark_mv : adc_mv;
    if (flicker_mv != 0 && flicker_hz > 0 && t1 > t0) {
        double w = 2.0 * M_PI * flicker_hz;
        mv += flicker_mv * (cos(w * t0) - cos(w * t1)) / (w * (t1 - t0));
    }
    return mv;
}

/* --- IRQ callbacks --------------------------------------------------------------------------------------------- */
static void adc_trigger(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    int ch = avr->data[0x7C] & 0x0F; /* ADMUX */
    double mv = ch == 1 ? (source() ? mon_mv : 0.0) : tia_mv(seconds());
    if (dither_lsb > 0) mv += dither_lsb * gauss() * 5000.0 / 1023.0;
    double units = mv * 10.0;
    if (units < 0) units = 0;
    if (units > 65535.0) units = 65535.0;
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ch == 1 ? ADC_IRQ_ADC1 : ADC_IRQ_ADC0),
                  (uint32_t)(units + 0.5));
}

/* --- the ADS1115 on the TWI --------------------------------------------------------------------------------------- */
#define ADS_ADDR 0x48
static struct {
    int present, selected, index;
    uint8_t pointer, wbuf[2];
    uint16_t config, lo_thresh, hi_thresh;
    int16_t conversion;
    uint64_t busy_until; /* cycle at which the running conversion ends (0: none) */
    double t_start;
} ads = {1, 0, 0, 0, {0, 0}, 0x8583, 0x8000, 0x7FFF, 0, 0, 0};
static avr_irq_t *ads_irq;

static const double ads_fs_mv[8] = {6144, 4096, 2048, 1024, 512, 256, 256, 256};
static const double ads_sps[8] = {8, 16, 32, 64, 128, 250, 475, 860};

/* the input AINp - AINn (mV) of a MUX setting: AIN0 = the amplifier's output, AIN1 its reference, AIN2/3 at 0 V */
static double ads_input(int mux, double t0, double t1)
{
    double ain[4] = {tia_mean_mv(t0, t1), ain1_mv, 0.0, 0.0};
    static const int pos[8] = {0, 0, 1, 2, 0, 1, 2, 3}, neg[8] = {1, 3, 3, 3, -1, -1, -1, -1};
    return ain[pos[mux]] - (neg[mux] < 0 ? 0.0 : ain[neg[mux]]);
}

static int16_t ads_code(double t0, double t1)
{
    int mux = (ads.config >> 12) & 7, pga = (ads.config >> 9) & 7;
    double lsb_mv = ads_fs_mv[pga] / 32768.0;
    double code = ads_input(mux, t0, t1) / lsb_mv;
    if (dither_lsb > 0) code += dither_lsb * gauss();
    code = floor(code + 0.5);
    if (code > 32767) code = 32767;
    if (code < -32768) code = -32768;
    return (int16_t)code;
}

static double ads_period(void) { return 1.0 / ads_sps[(ads.config >> 5) & 7]; }

/* bring the conversion register up to date: a finished single shot, or the last one of continuous mode */
static void ads_update(void)
{
    if (ads.busy_until && avr->cycle >= ads.busy_until) {
        ads.conversion = ads_code(ads.t_start, ads.t_start + ads_period());
        ads.busy_until = 0;
        ads.config |= 0x8000; /* OS reads 1: no conversion running */
    }
    if (!(ads.config & 0x0100)) { /* MODE 0: continuous conversions */
        double p = ads_period(), t1 = floor(seconds() / p) * p;
        ads.conversion = ads_code(t1 - p, t1);
    }
}

static void ads_write_reg(uint8_t reg, uint16_t v)
{
    ads_update();
    if (reg == 1) {
        int start = (v & 0x8000) && (v & 0x0100) && !ads.busy_until;
        ads.config = v & 0x7FFF;
        if (start) {
            ads.t_start = seconds();
            ads.busy_until = avr->cycle + (uint64_t)(ads_period() * FREQ + 0.5);
        } else if (!ads.busy_until) {
            ads.config |= 0x8000;
        }
    } else if (reg == 2) {
        ads.lo_thresh = v;
    } else if (reg == 3) {
        ads.hi_thresh = v;
    }
}

static uint16_t ads_read_reg(uint8_t reg)
{
    ads_update();
    switch (reg & 3) {
    case 0: return (uint16_t)ads.conversion;
    case 1: return ads.config;
    case 2: return ads.lo_thresh;
    default: return ads.hi_thresh;
    }
}

static void ads_twi(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    avr_twi_msg_irq_t v;
    v.u.v = value;
    if (v.u.twi.msg & TWI_COND_STOP) ads.selected = 0;
    if (v.u.twi.msg & TWI_COND_START) {
        ads.selected = 0;
        ads.index = 0;
        if (ads.present && (v.u.twi.addr >> 1) == ADS_ADDR) {
            ads.selected = v.u.twi.addr;
            avr_raise_irq(ads_irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, ads.selected, 1));
        }
    }
    if (!ads.selected) return;
    if (v.u.twi.msg & TWI_COND_WRITE) {
        avr_raise_irq(ads_irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_ACK, ads.selected, 1));
        if (ads.index == 0) ads.pointer = v.u.twi.data & 3;
        else if (ads.index <= 2) ads.wbuf[ads.index - 1] = v.u.twi.data;
        if (ads.index == 2) ads_write_reg(ads.pointer, (uint16_t)((ads.wbuf[0] << 8) | ads.wbuf[1]));
        ads.index++;
    }
    if (v.u.twi.msg & TWI_COND_READ) {
        uint16_t r = ads_read_reg(ads.pointer);
        uint8_t b = (ads.index & 1) ? (uint8_t)r : (uint8_t)(r >> 8); /* MSB, LSB, MSB, ... */
        avr_raise_irq(ads_irq + TWI_IRQ_INPUT, avr_twi_irq_msg(TWI_COND_READ, ads.selected, b));
        ads.index++;
    }
}

static void ads_attach(void)
{
    static const char *names[2] = {"8>ads1115.out", "32<ads1115.in"};
    ads_irq = avr_alloc_irq(&avr->irq_pool, 0, 2, names);
    avr_irq_register_notify(ads_irq + TWI_IRQ_OUTPUT, ads_twi, NULL);
    avr_connect_irq(ads_irq + TWI_IRQ_INPUT, avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT));
    avr_connect_irq(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), ads_irq + TWI_IRQ_OUTPUT);
}

static void report_pins(void);

/* reported at once, stamped with the cycle the firmware wrote the port at (a report after the run's burst would
 * carry a later time: a sleeping core jumps ahead by whole timer periods within a burst) */
static void pin_changed(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)value; (void)param;
    pins_dirty = 1;
    report_pins();
}

static void led_changed(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (!value || !sync_mode) return;
    if (!probe8(1) && queue_pos < queue_len) { /* a later repeat of the reading: its value came with the first */
        adc_mv = queue_mv[queue_pos++];
        if (dark_pos < dark_len) dark_mv = queue_dark[dark_pos++];
        return;
    }
    queue_pos = queue_len = 0;
    dark_pos = dark_len = have_dark = 0;
    say("SYNC first=%u n=%u nconv=%u gsel=%d source=%d chop=%d t=%.9f", probe8(1), probe_n(), probe_nconv(),
        gsel(), source(), chop_flag(), seconds());
    waiting_sync = 1;
}

static void uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (master < 0) return;
    uint8_t b = (uint8_t)value;
    if (write(master, &b, 1) < 0) {
        /* nobody reads the port: the byte is lost, as from a USB bridge whose host does not read */
    }
}

static void report_pins(void)
{
    pins_dirty = 0;
    if (gsel() == last_gsel && source() == last_source && reference() == last_reference) return;
    last_gsel = gsel();
    last_source = source();
    last_reference = reference();
    say("PIN gsel=%d source=%d reference=%d t=%.9f", last_gsel, last_source, last_reference, seconds());
}

/* a cycle timer at UNTIL's time: a sleeping core jumps from timer event to timer event, so this one stops it
 * there exactly (else it would run on to the firmware's next timer interrupt) */
static avr_cycle_count_t until_reached(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)when; (void)param;
    return 0;
}

static void sleep_cb(avr_t *a, avr_cycle_count_t how_long)
{
    (void)a; (void)how_long; /* never wait for wall time: simulated time is the emulated cycle count */
}

/* --- control channel ----------------------------------------------------------------------------------------- */
static void unplug(void)
{
    if (master >= 0) close(master);
    if (slave_keep >= 0) close(slave_keep);
    master = slave_keep = -1;
    in_len = 0;
}

static void noise(const char *hex)
{
    while (hex[0] && hex[1]) {
        unsigned b;
        if (sscanf(hex, "%2x", &b) != 1) break;
        uint8_t c = (uint8_t)b;
        if (master >= 0 && write(master, &c, 1) < 0) {
        }
        hex += 2;
    }
}

static void control_line(char *s)
{
    char word[16] = {0};
    double v = 0;
    int n = sscanf(s, "%15s %lf", word, &v);
    if (n < 1) return;
    if (!strcmp(word, "ADC") && n == 2) {
        adc_mv = v;
        waiting_sync = 0;
        /* more values: the following repeats of this reading, applied at their LED edges without a wait */
        char *p = s, *end;
        strtod(p + 4, &end);
        queue_pos = queue_len = 0;
        for (p = end; queue_len < MAX_QUEUE; p = end) {
            double q = strtod(p, &end);
            if (end == p) break;
            queue_mv[queue_len++] = q;
        }
    } else if (!strcmp(word, "DARKADC") && n == 2) {
        char *p, *end;
        dark_mv = v;
        have_dark = 1;
        strtod(s + 8, &end);
        dark_pos = dark_len = 0;
        for (p = end; dark_len < MAX_QUEUE; p = end) {
            double q = strtod(p, &end);
            if (end == p) break;
            queue_dark[dark_len++] = q;
        }
    } else if (!strcmp(word, "FLICKER") && n == 2) {
        double hz = 0;
        sscanf(s, "%*s %*f %lf", &hz);
        flicker_mv = v;
        flicker_hz = hz;
    } else if (!strcmp(word, "MON") && n == 2) {
        mon_mv = v;
    } else if (!strcmp(word, "AIN1") && n == 2) {
        ain1_mv = v;
    } else if (!strcmp(word, "ADS1115") && n == 2) {
        ads.present = v != 0;
    } else if (!strcmp(word, "DITHER") && n == 2) {
        dither_lsb = v;
    } else if (!strcmp(word, "SYNC") && n == 2) {
        sync_mode = v != 0;
        if (!sync_mode) waiting_sync = 0;
    } else if (!strcmp(word, "UNTIL") && n == 2) {
        uint64_t c = (uint64_t)(v * FREQ + 0.5);
        if (c > until_cycle) until_cycle = c;
        if (until_cycle > avr->cycle) {
            avr_cycle_timer_cancel(avr, until_reached, NULL);
            avr_cycle_timer_register(avr, until_cycle - avr->cycle, until_reached, NULL);
        }
    } else if (!strcmp(word, "TIME?")) {
        say("TIME t=%.9f", seconds());
    } else if (!strcmp(word, "RESET")) {
        avr_reset(avr);
        avr->data[0x54] = 1 << 1;                  /* MCUSR: EXTRF */
        in_len = 0;                                /* bytes in flight do not reach a board in reset */
        uart->input.read = uart->input.write = 0;
        queue_pos = queue_len = 0;
        dark_pos = dark_len = have_dark = 0;
        waiting_sync = 0;
        pins_dirty = 1;
    } else if (!strcmp(word, "FREEZE") && n == 2) {
        frozen = v != 0;
    } else if (!strcmp(word, "NOISE")) {
        char hex[1001];
        if (sscanf(s, "%*s %1000s", hex) == 1) noise(hex);
    } else if (!strcmp(word, "UNPLUG")) {
        unplug();
    } else if (!strcmp(word, "QUIT")) {
        quit_flag = 1;
    } else {
        fprintf(stderr, "avr_harness: unknown control line %s\n", s);
    }
}

static void read_control(void)
{
    for (;;) {
        ssize_t r = read(STDIN_FILENO, ctrl + ctrl_len, CTRL_SIZE - 1 - ctrl_len);
        if (r == 0) {
            quit_flag = 1;
            return;
        }
        if (r < 0) return; /* EAGAIN */
        ctrl_len += (size_t)r;
        char *nl;
        while ((nl = memchr(ctrl, '\n', ctrl_len))) {
            *nl = 0;
            control_line(ctrl);
            size_t used = (size_t)(nl - ctrl) + 1;
            memmove(ctrl, nl + 1, ctrl_len - used);
            ctrl_len -= used;
        }
        if (ctrl_len == CTRL_SIZE - 1) ctrl_len = 0; /* an overlong control line is dropped */
    }
}

static void read_pty(void)
{
    if (master < 0 || in_len == IN_SIZE) return;
    ssize_t r = read(master, inbuf + in_len, IN_SIZE - in_len);
    if (r > 0) in_len += (size_t)r;
}

/* bytes from the host into the UART's receive FIFO, as it has room (not before UNTIL's time) */
static void feed_uart(void)
{
    size_t k = 0;
    while (k < in_len && !uart_fifo_isfull(&uart->input) && avr->cycle >= until_cycle) {
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), inbuf[k]);
        k++;
    }
    if (k) {
        memmove(inbuf, inbuf + k, in_len - k);
        in_len -= k;
    }
}

static int idle(void)
{
    return avr->state == cpu_Sleeping && !probe8(0) && uart_fifo_isempty(&uart->input) && in_len == 0 &&
           avr->cycle >= until_cycle;
}

static void wait_events(int with_pty)
{
    struct pollfd p[2] = {{STDIN_FILENO, POLLIN, 0}, {master, POLLIN, 0}};
    int nfds = (with_pty && master >= 0 && in_len < IN_SIZE) ? 2 : 1;
    poll(p, (nfds_t)nfds, -1);
}

/* --- set-up ---------------------------------------------------------------------------------------------------- */
static int find_probe(elf_firmware_t *f)
{
    for (uint32_t i = 0; i < f->symbolcount; i++) {
        if (!strcmp(f->symbol[i]->symbol, "fw_probe")) {
            probe_addr = (uint16_t)(f->symbol[i]->addr & 0xFFFF);
            return 1;
        }
    }
    return 0;
}

static int open_pty(char *name)
{
    struct termios tio;
    if (openpty(&master, &slave_keep, name, NULL, NULL) < 0) return 0;
    tcgetattr(slave_keep, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave_keep, TCSANOW, &tio);
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    return 1;
}

int main(int argc, char **argv)
{
    const char *elf = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--dither") && i + 1 < argc) dither_lsb = atof(argv[++i]);
        else if (!strcmp(argv[i], "--no-ads1115")) ads.present = 0;
        else if (!strcmp(argv[i], "--seed") && i + 1 < argc) rng_state ^= strtoull(argv[++i], NULL, 10) * 0x2545F4914F6CDD1DULL;
        else elf = argv[i];
    }
    if (!elf) {
        fprintf(stderr, "usage: avr_harness [--dither LSB] [--seed N] [--no-ads1115] firmware.elf\n");
        return 2;
    }
    avr_global_logger_set(logger);
    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    if (elf_read_firmware(elf, &f) != 0) {
        fprintf(stderr, "avr_harness: cannot read the firmware %s\n", elf);
        return 2;
    }
    if (!find_probe(&f)) {
        fprintf(stderr, "avr_harness: %s has no symbol fw_probe (not the detector firmware?)\n", elf);
        return 2;
    }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) return 2;
    avr_init(avr);
    f.frequency = FREQ;
    avr_load_firmware(avr, &f);
    avr->avcc = avr->aref = VREF_UNITS;
    avr->vcc = VREF_UNITS;
    avr->sleep = sleep_cb;
    avr->log = LOG_WARNING;
    for (avr_io_t *io = avr->io_port; io; io = io->next)
        if (io->kind && !strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0') uart = (avr_uart_t *)io;
    if (!uart) return 2;
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_trigger, NULL);
    for (int pin = 0; pin < 3; pin++)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), pin), pin_changed, NULL);
    for (int pin = 6; pin < 8; pin++)
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), pin), pin_changed, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 5), led_changed, NULL);
    ads_attach();

    char name[256];
    if (!open_pty(name)) {
        perror("avr_harness: openpty");
        return 2;
    }
    fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);
    say("PTY %s vref_mv=5000 full=1023 ads1115=0x%02x", name, ADS_ADDR);

    while (!quit_flag) {
        read_control();
        read_pty();
        if (pins_dirty) report_pins();
        if (waiting_sync || frozen) {
            wait_events(0);
            continue;
        }
        feed_uart();
        if (idle()) {
            wait_events(1);
            continue;
        }
        for (int i = 0; i < 2000 && !waiting_sync; i++) {
            int st = avr_run(avr);
            if (st == cpu_Done || st == cpu_Crashed) {
                say("BYE firmware %s at t=%.6f", st == cpu_Done ? "stopped" : "crashed", seconds());
                return 1;
            }
            if (idle()) break;
            if (in_len && avr->cycle >= until_cycle && !uart_fifo_isfull(&uart->input)) break; /* bytes to feed */
        }
    }
    say("BYE quit");
    return 0;
}

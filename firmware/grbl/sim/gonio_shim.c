/*
  gonio_shim.c - gonio-brdf's shim for grbl-sim, GRBL 1.1h's host simulator (a test fixture, never flashed).

  Linked into grbl_sim.exe by `make -C firmware/grbl sim` with `-Wl,--wrap=...`: grbl-sim's and GRBL's files stay
  as they are; this file replaces six of grbl-sim's functions (sim_loop, platform_start_thread,
  platform_poll_stdin, _delay_ms, _delay_us, serial_read) and runs the clock around two of GRBL's (st_prep_buffer,
  serial_write: their callers are in GRBL's other files).

  1. One CPU, as on the ATmega328P. grbl-sim runs GRBL's main loop in one thread and its simulated clock and
     interrupt routines in another (sim_loop), unsynchronised: cli() only clears a flag, so on a multi-core host
     an interrupt routine runs *beside* the main loop, and its clock follows the wall clock, so a main loop
     descheduled by a busy machine sees the stepper interrupt empty the segment buffer under it (the stalls
     and off-by-a-step positions of a loaded machine). Here the clock runs *in* GRBL's thread: each time GRBL's
     main loop passes one of the points where it waits or polls (serial_read, st_prep_buffer, serial_write with
     its buffer full, _delay_ms/_delay_us), and GRBL's interrupt flag is set, TURN_TICKS ticks of the 16 MHz
     clock run there (timers, their interrupt routines, the UART), as if the interrupts had fired at that
     point. Simulated time advances only as GRBL's main loop runs, so a busy host slows the simulation down and
     nothing else. For the few loops of GRBL that wait for an interrupt without calling anything (the limit
     alarm waiting for a reset), the clock thread (our sim_loop) sends GRBL's thread a signal when no turn ran
     for a millisecond; its handler runs a turn there, if GRBL is not inside cli().
  2. Limit switches. grbl-sim leaves the pins at 0, so GRBL reads every limit, control and probe input as active
     and homing cannot work. Here each arm's step pulses (the STEP/DIR outputs GRBL writes, as a driver sees
     them) move a simulated arm, whose switch pulls its limit pin low while the arm is at or beyond it
     (normally-open switches to GND, GRBL's pull-ups); a pin change raises GRBL's limit pin-change interrupt when
     GRBL enables it (hard limits, $21=1). Unconnected inputs read high (pulled up): not pressed.
     GONIO_GRBL_SWITCHES="x=-150,y=-200": each arm starts 150 / 200 steps below its switch (a negative start:
     the switch is at the + end; positive: at the - end); an axis not named has no switch (Z here; "y" left
     out: a switch that never closes). GONIO_GRBL_SLIP="y:+200@400": after its 400th step the Y arm slips by
     +200 steps (a belt jumping teeth: GRBL's count and the arm disagree from then on).
  3. Serial input read with read(2) straight from the descriptor, so stdio's buffer never holds bytes back
     (grbl-sim read stdin with getchar, which needed `stdbuf -i0`).
*/

#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "simulator.h"
#include "avr/interrupt.h"
#include "avr/io.h"

#define TURN_SIGNAL SIGUSR2
#define TURN_TICKS 1600ULL          /* 100 us of the 16 MHz clock per turn of the interrupts */
#define IDLE_CHECK_NS 1000000L      /* the clock thread looks every 1 ms whether a turn ran */
#define POLL_EVERY_TICKS 1600ULL    /* read the serial input at most every 100 us of simulated time */

extern sim_hook_fp sim_hook[4];     /* grbl-sim's hooks: [1] per tick, [2] per byte (simulator.c) */
void simulate_hardware(bool do_serial);
void simulate_write_interrupt(void);  /* grbl-sim's UART transmit (serial.c) */

static pthread_t grbl_thread;
static volatile sig_atomic_t have_thread, in_ticks;
static volatile unsigned long turns;  /* turns run so far (read by the clock thread) */
static uint64_t next_byte_tick;

/* -- switches ------------------------------------------------------------------------------------------------- */
static int has_switch[N_AXIS], switch_above[N_AXIS];
static int64_t arm[N_AXIS];          /* steps from the switch's trigger point (>= 0 / <= 0: pressed) */
static uint64_t steps_seen[N_AXIS];
static int slip_axis = -1;
static int64_t slip_by;
static uint64_t slip_at;
static uint8_t last_steps;

static int axis_index(char c)
{
  switch (c) {
    case 'x': case 'X': return X_AXIS;
    case 'y': case 'Y': return Y_AXIS;
    case 'z': case 'Z': return Z_AXIS;
    default: return -1;
  }
}

static void switches_init(void)
{
  const char *s = getenv("GONIO_GRBL_SWITCHES");
  char buf[256];
  if (s) {
    strncpy(buf, s, sizeof buf - 1);
    buf[sizeof buf - 1] = 0;
    for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
      int a = axis_index(tok[0]);
      if (a < 0 || tok[1] != '=') { fprintf(stderr, "GONIO_GRBL_SWITCHES: cannot read %s\n", tok); exit(2); }
      long start = strtol(tok + 2, NULL, 10);
      has_switch[a] = 1;
      switch_above[a] = start <= 0;
      arm[a] = start;
    }
  }
  const char *p = getenv("GONIO_GRBL_SLIP");
  if (p && p[0]) {
    char axis = 0;
    long by = 0;
    unsigned long long at = 0;
    if (sscanf(p, "%c:%ld@%llu", &axis, &by, &at) != 3 || axis_index(axis) < 0) {
      fprintf(stderr, "GONIO_GRBL_SLIP: expected e.g. y:+200@400, got %s\n", p);
      exit(2);
    }
    slip_axis = axis_index(axis);
    slip_by = by;
    slip_at = at;
  }
  CONTROL_PIN |= CONTROL_MASK;  /* reset, feed hold, cycle start: pulled up, not pressed */
  PROBE_PIN |= PROBE_MASK;      /* no probe */
}

static void set_limit_pins_at_power_up(void);

static uint8_t limit_levels(void)
{
  uint8_t level = LIMIT_MASK;   /* pulled up */
  for (int a = 0; a < N_AXIS; a++) {
    if (!has_switch[a]) { continue; }
    bool pressed = switch_above[a] ? arm[a] >= 0 : arm[a] <= 0;
    if (pressed) { level &= ~get_limit_pin_mask(a); }
  }
  return level;
}

static void set_limit_pins_at_power_up(void)
{
  LIMIT_PIN = (LIMIT_PIN & ~LIMIT_MASK) | limit_levels();
}

/* after each tick: count the step pulses GRBL put out, move the arms, set the limit pins */
static void switches_tick(void)
{
  uint8_t active = (STEP_PORT ^ settings.step_invert_mask) & STEP_MASK;
  uint8_t rising = active & ~last_steps;
  last_steps = active;
  if (rising) {
    uint8_t dir = DIRECTION_PORT ^ settings.dir_invert_mask;
    for (int a = 0; a < N_AXIS; a++) {
      if (!(rising & get_step_pin_mask(a))) { continue; }
      arm[a] += (dir & get_direction_pin_mask(a)) ? -1 : 1;
      if (++steps_seen[a] == slip_at && a == slip_axis) { arm[a] += slip_by; }
    }
  }
  uint8_t before = LIMIT_PIN & LIMIT_MASK;
  uint8_t after = limit_levels();
  if (before != after) {
    LIMIT_PIN = (LIMIT_PIN & ~LIMIT_MASK) | after;
    if (((before ^ after) & LIMIT_PCMSK) && (PCICR & (1 << LIMIT_INT)) && (io.sreg & SEI) && pc_vect) {
      pc_vect();  /* GRBL's limit pin-change interrupt (hard limits) */
    }
  }
}

/* -- the clock ------------------------------------------------------------------------------------------------- */
static void run_ticks(uint64_t n)
{
  uint64_t end = sim.masterclock + n;
  while (sim.masterclock < end) {
    bool read_serial = sim.masterclock >= next_byte_tick;
    simulate_hardware(read_serial);
    switches_tick();
    sim_hook[1]();
    if (read_serial) {
      sim.baud_ticks = 2 * ((UBRR0H << 8) + UBRR0L) + 1;
      if (UCSR0A & (1 << U2X0)) { sim.baud_ticks *= 2; }
      next_byte_tick += sim.baud_ticks;
      sim_hook[2]();
    }
  }
}

/* a turn of the interrupts at this point of GRBL's main loop, if GRBL allows interrupts here */
static void turn(void)
{
  if (in_ticks) { return; }
  in_ticks = 1;
  if (io.sreg & SEI) {
    run_ticks(TURN_TICKS);
  } else {
    /* inside cli(): no time passes, but the UART still sends what GRBL queued (grbl-sim never gated it, and
       GRBL 1.1h prints its settings before its first sei() when the EEPROM is new) */
    simulate_write_interrupt();
  }
  turns++;
  in_ticks = 0;
}

static void on_turn(int sig)
{
  (void)sig;
  int saved = errno;
  turn();
  errno = saved;
}

static void busy_wait_ticks(uint64_t n)
{
  if (in_ticks || !(io.sreg & SEI)) { return; }
  in_ticks = 1;
  run_ticks(n);
  turns++;
  in_ticks = 0;
}

void __wrap__delay_ms(int ms) { busy_wait_ticks((uint64_t)ms * (F_CPU / 1000)); }
void __wrap__delay_us(int us) { busy_wait_ticks((uint64_t)us * (F_CPU / 1000000)); }

/* the main loop's waiting points (grbl-sim's serial_read slept 0 us there: not needed, one thread) */
uint8_t orig_serial_read(void);
uint8_t __wrap_serial_read(void)
{
  turn();
  return orig_serial_read();
}

void __real_st_prep_buffer(void);
void __wrap_st_prep_buffer(void)
{
  turn();
  __real_st_prep_buffer();
}

extern uint8_t serial_tx_buffer_head;
extern volatile uint8_t serial_tx_buffer_tail;
void __real_serial_write(uint8_t data);
void __wrap_serial_write(uint8_t data)
{
  uint8_t next = serial_tx_buffer_head + 1;
  if (next == TX_BUFFER_SIZE + 1) { next = 0; }  /* GRBL serial.c's TX_RING_BUFFER */
  while (next == serial_tx_buffer_tail && !(sys_rt_exec_state & EXEC_RESET)) { turn(); }  /* buffer full */
  __real_serial_write(data);
}

plat_thread_t *__real_platform_start_thread(plat_threadfunc_t f);
plat_thread_t *__wrap_platform_start_thread(plat_threadfunc_t f)
{
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_turn;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  sigaction(TURN_SIGNAL, &sa, NULL);
  switches_init();
  set_limit_pins_at_power_up();
  plat_thread_t *th = __real_platform_start_thread(f);
  if (th) {
    grbl_thread = th->tid;
    have_thread = 1;
  }
  return th;
}

static char out_buf[3][4096];

void __wrap_sim_loop(void)
{
  /* stdio buffers now, not at their first use inside GRBL's thread's signal handler (no malloc there) */
  FILE *files[3] = {args.serial_out_file, args.block_out_file, args.step_out_file};
  for (int i = 0; i < 3; i++) {
    bool seen = files[i] == stderr;
    for (int j = 0; j < i; j++) { seen = seen || files[j] == files[i]; }
    if (!seen) { setvbuf(files[i], out_buf[i], _IOLBF, sizeof out_buf[i]); }
  }
  if (!have_thread) { return; }
  unsigned long seen_turns = turns;
  while (sim.exit != exit_OK) {
    struct timespec ts = {0, IDLE_CHECK_NS};
    nanosleep(&ts, NULL);
    if (turns == seen_turns) { pthread_kill(grbl_thread, TURN_SIGNAL); }  /* GRBL waits without a hook */
    seen_turns = turns;
  }
}

/* -- serial input ---------------------------------------------------------------------------------------------- */
static unsigned char in_buf[256];
static int in_n, in_i;
static uint64_t last_poll_tick;
static bool polled_once;

uint8_t __wrap_platform_poll_stdin(void)
{
  if (in_i < in_n) { return in_buf[in_i++]; }
  if (polled_once && sim.masterclock - last_poll_tick < POLL_EVERY_TICKS) { return 0; }
  polled_once = true;
  last_poll_tick = sim.masterclock;
  struct pollfd p = {STDIN_FILENO, POLLIN, 0};
  if (poll(&p, 1, 0) <= 0) { return 0; }
  if (p.revents & POLLIN) {
    ssize_t n = read(STDIN_FILENO, in_buf, sizeof in_buf);
    if (n > 0) {
      in_n = (int)n;
      in_i = 1;
      return in_buf[0];
    }
    if (n < 0 && (errno == EINTR || errno == EAGAIN)) { return 0; }
    return 0xFF;  /* end of input: grbl-sim exits once idle */
  }
  return (p.revents & (POLLHUP | POLLERR)) ? 0xFF : 0;
}

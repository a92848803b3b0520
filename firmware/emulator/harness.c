/* labrig-emu: the real compiled bridge firmware under simavr, UART0 on a pty, the ADC fed
 * by a DC servo plant model and the MCP4822 decoded from SPI + CS.
 *
 *   labrig-emu --fw build/uno/labrig_bridge.elf [--board uno|mega] [plant options]
 *
 * Prints the pty path as the first line of stdout, then serves until SIGINT/SIGTERM, or
 * until the process that started it dies (even by SIGKILL): nothing has to find and kill
 * a leftover emulator. --parent-pid names that process (closes the start-up race).
 * The simulation is paced to real time (--speed 1) so host timeouts and the firmware's
 * watchdog behave as on the bench; --speed 0 runs free.
 *
 * Analog front end as in docs/hardware.md: bridge output u = (VA - VB) * 2.4414 with
 * channel B at mid-scale, so u = (wordA - wordB) * 10 V / 4096; sensors of +-10 V map onto
 * 0..5 V by (s + 10) / 4. A2 (input pot / reference) carries the bridge output u.
 * Closed loop: the harness snoops host->board CONFIGURE frames for the loop mode (the
 * emulated patch panel, re-patched as each run says) unless --loop open|closed forces it;
 * the analog loop's gains are --kp and --kv (the rig file's patched knobs).
 *
 * --rig hbridge: the H-bridge + encoder firmware (make RIG=hbridge) against motor.c. Every
 * microsecond the plant reads the bridge's inputs as the chip drives them -- Timer1's own
 * registers (mode, TOP, compare values, COM bits) and the PORTB bits of pins the timer does
 * not drive -- and moves the encoder's A/B pins at the step where the shaft crosses an
 * edge. --enc-log FILE records "T cycle" when the sample clock (Timer2) starts, "E cycle
 * edge" at every encoder edge and "D cycle duty" whenever the commanded signed duty (in
 * timer counts) changes. --index drives the encoder's index pin (Uno/Nano D4, Mega D19) high
 * once a turn of the encoder's shaft, gated to one quadrature state (A = B = high, half a
 * turn from where the shaft rests at reset), logged "X cycle edge" as it rises.
 * --miss-edges N withholds every Nth edge's pin change, so the next edge moves both
 * channels at once: a shaft outrunning the chip's interrupts, whose count it cannot decode.
 *
 * --bootloader FILE.hex loads a bootloader into its section and starts there, as the
 * BOOTRST fuse does (without --fw the application flash is erased): avrdude then uploads
 * through it over the pty as on the bench (labrig flash's test), and the bootloader starts
 * what it wrote.
 *
 * --eeprom FILE keeps the chip's EEPROM (the board's id) in FILE across runs: read at start
 * (a missing file: erased), written back when the harness ends. */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_hex.h"
#include "sim_irq.h"
#include "sim_io.h"
#include "avr_adc.h"
#include "avr_eeprom.h"
#include "avr_spi.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "uart_pty.h"

#include "plant.h"
#include "motor.h"
#include "lr_proto.h"

static avr_t *avr;
static uart_pty_t pty;
static plant_t plant;
static volatile sig_atomic_t stop_flag;
static double sim_t;                 /* plant time, s */
static int stuck_adc = -1;           /* --stuck-adc N: this analog input reads 5 V */
static uint16_t word_a = 0, word_b = 0;  /* MCP4822 powers up shut down: 0 V on both */
static int on_a = 0, on_b = 0;
static uint8_t spi_bytes[4];
static int spi_n;
static FILE *dac_log;
static int loop_forced = -1;
static lr_decoder_t snoop;
static const double DT = 10e-6;

static double now_s(void) { return (double)avr->cycle / (double)avr->frequency; }

/* the E-stop (--estop-at S): a normally-closed switch holding D7 low (Uno PD7, Mega PH4),
 * opened S seconds of chip time after the bridge first drives the motor (a host that starts
 * slowly on a busy machine moves the run, not the test's moment within it) */
static double estop_at = -1.0;
static double first_drive_s = -1.0;   /* when the output first left 0 V */
static char estop_port;
static int estop_bit;

/* every 1 ms: the switch's level on the pin (held, so that the firmware setting up its
 * pull-up cannot raise it), low until estop_at, then high */
static avr_cycle_count_t estop_hold(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a; (void)param;
    int open = first_drive_s >= 0.0 && now_s() >= first_drive_s + estop_at;
    static int said;
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(estop_port), estop_bit), open);
    if (open && !said) {
        said = 1;
        fprintf(stderr, "labrig-emu: E-stop pressed at %.6f s (driving since %.6f s)\n", now_s(),
                first_drive_s);
        fflush(stderr);
    }
    return when + 16000;
}

static void advance(void)
{
    double t = now_s();
    while (sim_t + DT <= t) { plant_step(&plant, DT); sim_t += DT; }
}

static double bridge_out(void)
{
    double va = on_a ? word_a * 2.048 * 2 / 4096.0 : 0.0;   /* gain 2x */
    double vb = on_b ? word_b * 2.048 * 2 / 4096.0 : 0.0;
    return (va - vb) * (5.0 / 2.048);          /* bipolar stage: (VA - VB) * 2.441, +-5 V */
}

/* ADC conversion started: give it the sensor voltage of that instant */
static void adc_trigger(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    union { avr_adc_mux_t mux; uint32_t v; } e = {.v = value};
    if (e.mux.kind != ADC_MUX_SINGLE || e.mux.src > 2) return;
    advance();
    double s = e.mux.src == 0 ? plant_tacho_v(&plant) : e.mux.src == 1 ? plant_pos_v(&plant) : plant.u;
    double vin = (s + 10.0) / 4.0;
    if (vin < 0) vin = 0;
    if (vin > 5.0) vin = 5.0;
    if (e.mux.src == stuck_adc) vin = 5.0;   /* a broken wire: the pin at its rail */
    /* simavr scales by 1023/Vref where the chip uses 1024/Vref: compensate */
    uint32_t mv = (uint32_t)(vin * 1000.0 * 1024.0 / 1023.0 + 0.5);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + e.mux.src), mv);
}

static void spi_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (spi_n < 4) spi_bytes[spi_n++] = (uint8_t)value;
}

static void cs_pin(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (!value) { spi_n = 0; return; }          /* falling edge: a new word starts */
    if (spi_n == 2) {                             /* rising edge latches (LDAC tied low) */
        uint16_t cmd = (uint16_t)(spi_bytes[0] << 8 | spi_bytes[1]);
        int ch = cmd >> 15, active = (cmd >> 12) & 1;
        uint16_t w = cmd & 0x0FFF;
        advance();
        if (ch == 0) {
            int changed = (w != word_a) || (active != on_a);
            if (w != 2048 && active && first_drive_s < 0.0) first_drive_s = now_s();
            word_a = w; on_a = active;
            if (changed && dac_log) { fprintf(dac_log, "%.6f %u\n", now_s(), w); fflush(dac_log); }
        } else {
            word_b = w; on_b = active;
        }
        plant.u = bridge_out();
    }
    spi_n = 0;
}

/* ---- the serial line's speed. A pty carries bytes whatever speed either end sets; a USB
 * serial line does not: a UART receiving at another baud rate than the sender's reads
 * framing errors and garbage. So each byte crosses only when the speed the host set on the
 * pty (its termios, shared by master and slave) is within 4 % of the chip's own UART rate
 * (UBRR0 and U2X0), else it arrives as garbage, both ways: a wrong --baud or a board flashed
 * for another fails as on the bench. */
static long pty_baud(void)
{
    struct termios t;
    if (tcgetattr(pty.pty.s, &t) != 0) return 0;
    switch (cfgetospeed(&t)) {
    case B9600: return 9600;
    case B19200: return 19200;
    case B38400: return 38400;
    case B57600: return 57600;
    case B115200: return 115200;
    case B230400: return 230400;
    case B460800: return 460800;
    case B500000: return 500000;
    case B921600: return 921600;
    case B1000000: return 1000000;
    default: return 0;   /* another speed (BOTHER): not judged */
    }
}

static int line_garbles(void)
{
    /* UCSR0A 0xC0 (U2X0 bit 1), UBRR0L 0xC4, UBRR0H 0xC5: the same on the 328P and 2560 */
    long host = pty_baud();
    if (!host) return 0;
    double ubrr = ((avr->data[0xC5] << 8) | avr->data[0xC4]) & 0x0FFF;
    double chip = 16e6 / ((avr->data[0xC0] & 0x02 ? 8.0 : 16.0) * (ubrr + 1.0));
    double r = host / chip;
    return r < 0.96 || r > 1.04;
}

static uint8_t garbage(uint32_t b) { return (uint8_t)(b * 167u + 13u); }

/* ---- board -> host. A real board's USB-serial chip hands its bytes to the host's USB
 * stack, which polls whatever the reading program does and keeps them in the tty buffer.
 * simavr's uart_pty instead keeps them in a 512-byte FIFO emptied by a thread polling
 * every 500 us: a 56 ms gap in that thread's scheduling (a busy 2-core machine) wraps the
 * FIFO, which then reads empty -- five SAMPLES frames gone without a trace -- and a short
 * write to a full pty drops the rest of its chunk. So the harness keeps the chip's bytes
 * in its own buffer (7 s of a 1 kHz run) and writes them to the pty master itself, from
 * the simulation's loop, which must run anyway to keep real time; a byte that finds the
 * buffer full (a host that stopped reading) is counted and said. */
#define TO_HOST_SIZE 65536u
static uint8_t to_host[TO_HOST_SIZE];
static uint32_t to_host_r, to_host_w;   /* free-running; the difference is the fill */
static unsigned long to_host_dropped, to_host_dropped_said;

static void chip_to_host(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    if (to_host_w - to_host_r >= TO_HOST_SIZE) { to_host_dropped++; return; }
    to_host[to_host_w++ % TO_HOST_SIZE] = line_garbles() ? garbage(value) : (uint8_t)value;
}

static void flush_to_host(void)
{
    while (to_host_w != to_host_r) {
        uint32_t at = to_host_r % TO_HOST_SIZE;
        uint32_t n = to_host_w - to_host_r;
        if (n > TO_HOST_SIZE - at) n = TO_HOST_SIZE - at;
        ssize_t k = write(pty.pty.s, to_host + at, n);   /* the master, non-blocking */
        if (k <= 0) break;   /* the pty is full (or the host closed it): later */
        to_host_r += (uint32_t)k;
    }
    if (to_host_dropped > to_host_dropped_said) {
        fprintf(stderr, "labrig-emu: the host is not reading: %lu bytes to it dropped\n",
                to_host_dropped);
        fflush(stderr);
        to_host_dropped_said = to_host_dropped;
    }
}

static void host_to_chip(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT),
                  line_garbles() ? garbage(value) : value);
}

/* host -> board bytes: the patch panel is patched open or closed as each CONFIGURE's loop
 * mode says (a student re-patching between runs); its gains are the knobs' (--kp, --kv,
 * from the rig file), never the gains a plan sends the board, which no patch panel reads */
static void uart_in(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    lr_frame_t f;
    if (lr_decoder_feed(&snoop, (uint8_t)value, &f) && f.type == LR_CONFIGURE &&
        f.body_len >= LR_CONFIGURE_FIXED && loop_forced < 0) {
        advance();
        plant.p.closed = f.body[0] == LR_LOOP_CLOSED;
    }
}


/* ---- the H-bridge rig ------------------------------------------------------------------ */
static int rig_hbridge;
static motor_t motor;
static FILE *enc_log;
static int pin_a_bit, pin_b_bit;            /* Timer1's OC1A/OC1B on PORTB */
static char enc_port;
static int enc_a_bit, enc_b_bit;
static int idx_on, idx_bit, idx_level;      /* the index: on PORTD (Uno PD4, Mega PD2) */
static int64_t idx_per_turn, idx_at;        /* edges a turn, and the edge it marks */
static long miss_every;                     /* withhold every Nth edge's pin change */
static uint64_t edges_seen;
static avr_cycle_count_t last_cycle;
static int64_t edge_now;
static int timer2_on;
static long duty_logged = 0x7FFFFFFF;
static uint64_t pwm_period;
enum { R_TCCR1A = 0x80, R_TCCR1B = 0x81, R_ICR1 = 0x86, R_OCR1A = 0x88, R_TCCR2A = 0xB0, R_TCCR2B = 0xB1,
       R_PORTB = 0x25 };
enum { LVL_LOW, LVL_HIGH, LVL_PWM, LVL_PWM_INV };

static uint16_t reg16(int lo) { return (uint16_t)(avr->data[lo] | avr->data[lo + 1] << 8); }

static int level_kind(int com, int port_bit)
{
    if (com == 2) return LVL_PWM;
    if (com == 3) return LVL_PWM_INV;
    return port_bit ? LVL_HIGH : LVL_LOW;
}

/* the level of a pin in the part of the period before (first = 1) or after the compare */
static int level_in(int kind, int first)
{
    if (kind == LVL_PWM) return first;
    if (kind == LVL_PWM_INV) return !first;
    return kind == LVL_HIGH;
}

/* cycles c in [c0, c1) whose phase c mod P lies in [a, b) */
static double window_cycles(uint64_t c0, uint64_t c1, uint64_t P, uint64_t a, uint64_t b)
{
    if (b <= a) return 0.0;
    uint64_t w = b - a;
#define F(x) ((double)((x) / P) * (double)w + (double)(((x) % P) > a ? ((((x) % P) - a) < w ? (((x) % P) - a) : w) : 0))
    return F(c1) - F(c0);
#undef F
}

/* the bridge over the cycles [c0, c1), from Timer1's registers and PORTB */
static bridge_step_t bridge_inputs(uint64_t c0, uint64_t c1, long *duty_out)
{
    bridge_step_t st = {0.0, 1, 0};
    uint8_t tccr1a = avr->data[R_TCCR1A], tccr1b = avr->data[R_TCCR1B], portb = avr->data[R_PORTB];
    int running = (tccr1b & 7) != 0 && (tccr1b & 0x18) == 0x18 && (tccr1a & 3) == 2;  /* mode 14 */
    uint64_t P = (uint64_t)reg16(R_ICR1) + 1;
    /* fast PWM double-buffers the compare value: a write takes effect when the timer
     * wraps at TOP, as on the chip (the phase of the wrap is taken from the cycle count) */
    static uint64_t ocr_active;
    if (c1 / P != c0 / P || P != pwm_period) ocr_active = reg16(R_OCR1A);
    pwm_period = P;
    uint64_t H = ocr_active + 1;
    if (H > P) H = P;
    int ka = level_kind(running ? (tccr1a >> 6) & 3 : 0, (portb >> pin_a_bit) & 1);
    int kb = level_kind(running ? (tccr1a >> 4) & 3 : 0, (portb >> pin_b_bit) & 1);
    /* two parts of the period: [0, H) before the compare, [H, P) after */
    int drive[2], dir[2], brake[2];
    for (int part = 0; part < 2; part++) {
        int a = level_in(ka, part == 0), b = level_in(kb, part == 0);
        if (!motor.p.in1_in2) {      /* PWM + DIR: EN = a, DIR = b (high: reverse) */
            drive[part] = a; dir[part] = b ? -1 : 1; brake[part] = motor.p.brake;
        } else {                     /* IN1/IN2: 10 forward, 01 reverse, 11 brake, 00 coast */
            drive[part] = a != b; dir[part] = a ? 1 : -1; brake[part] = a && b;
        }
    }
    uint64_t lo[2] = {0, H}, hi[2] = {H, P};
    double driven = 0.0;
    long duty = 0;
    for (int part = 0; part < 2; part++) {
        if (!drive[part] || hi[part] <= lo[part]) { st.brake = brake[part]; continue; }
        st.dir = dir[part];
        duty = dir[part] * (long)(hi[part] - lo[part]);
        if (drive[!part] || hi[!part] <= lo[!part]) {   /* driven the whole period: no pulses */
            driven = 1.0;
            duty = dir[part] * (long)P;
            break;
        }
        /* each pulse loses its first dead cycles: the bridge's turn-on delay */
        double dead_v = dir[part] > 0 ? motor.p.dead_fwd : motor.p.dead_rev;
        uint64_t dead = (uint64_t)llround(dead_v / motor.p.supply * (double)P);
        driven = window_cycles(c0, c1, P, lo[part] + dead, hi[part]) / (double)(c1 - c0);
    }
    st.driven = driven;
    *duty_out = duty;
    return st;
}

static void encoder_pins(int64_t e)
{
    /* forward: A leads B. At the angle 0 both channels are high, the level an open-
     * collector encoder's pull-ups give: the pins the chip reads at reset are the encoder's */
    static const uint8_t gray[4] = {3, 1, 0, 2};
    uint8_t ab = gray[((e % 4) + 4) % 4];
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(enc_port), enc_a_bit), (ab >> 1) & 1);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(enc_port), enc_b_bit), ab & 1);
}

/* every microsecond of simulated time: the bridge's inputs, the plant, the encoder */
static avr_cycle_count_t motor_tick(avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)param;
    uint64_t now = a->cycle;
    if (now > last_cycle) {
        long duty;
        bridge_step_t st = bridge_inputs(last_cycle, now, &duty);
        motor_step(&motor, &st, (double)(now - last_cycle) / (double)a->frequency);
        last_cycle = now;
        if (duty != 0 && first_drive_s < 0.0) first_drive_s = now_s();
        if (enc_log && duty != duty_logged) {
            fprintf(enc_log, "D %llu %ld\n", (unsigned long long)now, duty);
            duty_logged = duty;
        }
    }
    int64_t e = motor_edge(&motor);
    while (e != edge_now) {            /* one pin change per edge, in order */
        edge_now += e > edge_now ? 1 : -1;
        if (!miss_every || ++edges_seen % (uint64_t)miss_every) encoder_pins(edge_now);
        if (enc_log) fprintf(enc_log, "E %llu %lld\n", (unsigned long long)now, (long long)edge_now);
        if (idx_on) {
            int level = ((edge_now - idx_at) % idx_per_turn + idx_per_turn) % idx_per_turn == 0;
            if (level != idx_level) {
                avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), idx_bit), level);
                idx_level = level;
                if (level && enc_log)
                    fprintf(enc_log, "X %llu %lld\n", (unsigned long long)now, (long long)edge_now);
            }
        }
    }
    /* the sample clock: Timer2 in CTC at clk/8 (Arduino's own start-up set-up of Timer2
     * for analogWrite is not it) */
    int t2 = (avr->data[R_TCCR2B] & 7) == 2 && (avr->data[R_TCCR2A] & 3) == 2;
    if (t2 && !timer2_on && enc_log) fprintf(enc_log, "T %llu\n", (unsigned long long)now);
    timer2_on = t2;
    return when + 16;
}

/* the current-sense amplifier on A0: its output at zero current and its V per A, as a
 * bidirectional sense amplifier (ACS712, INA240 at mid-supply) gives it; 0 V per A: none */
static double sense_zero_v = 2.5, sense_v_per_a = 0.0;

/* an H-bridge board's conversion of A0 started: the armature current of that instant */
static void adc_trigger_current(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq; (void)param;
    union { avr_adc_mux_t mux; uint32_t v; } e = {.v = value};
    if (e.mux.kind != ADC_MUX_SINGLE || e.mux.src != 0) return;
    double vin = sense_zero_v + sense_v_per_a * motor.i;
    if (vin < 0) vin = 0;
    if (vin > 5.0) vin = 5.0;
    if (enc_log) fprintf(enc_log, "I %llu %.9g\n", (unsigned long long)avr->cycle, motor.i);
    uint32_t mv = (uint32_t)(vin * 1000.0 * 1024.0 / 1023.0 + 0.5);   /* see adc_trigger */
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0), mv);
}

static void on_signal(int sig) { (void)sig; stop_flag = 1; }

static void usage(void)
{
    fprintf(stderr,
        "usage: labrig-emu --fw FILE.elf [--board uno|nano|mega] [--speed X] [--dac-log FILE]\n"
        "  [--bootloader FILE.hex]  (run it from reset; without --fw, the flash is erased)\n"
        "  [--eeprom FILE]  (the EEPROM read from FILE at start, written back at exit)\n"
        "  [--stuck-adc N]  (MS150: analog input N (0 tacho, 1 pot, 2 ref) stuck at 5 V)\n"
        "  [--link PATH] [--loop auto|open|closed] [--kp G] [--kv G]\n"
        "  [--R ohm] [--L H] [--J kgm2] [--B Nms] [--K Nm/A] [--Ka V/V] [--Vmax V] [--N ratio]\n"
        "  [--Kt V/(rad/s)] [--Kpot V/rad] [--pos-offset V] [--noise-tacho V] [--noise-pos V]\n"
        "  [--Tc Nm] [--seed N] [--parent-pid PID]\n"
        "  H-bridge rig: --rig hbridge [--supply V] [--drop V] [--dead-fwd V] [--dead-rev V]\n"
        "  [--Ts Nm] [--backlash rad] [--encoder-on-output] [--lines N] [--in1-in2] [--brake]\n"
        "  [--enc-log FILE] [--current-v-per-a V/A] [--current-zero V] [--index]\n"
        "  [--estop-at S]   (an E-stop on D7, closed, opened S s after the output first moves)\n"
        "  [--miss-edges N]\n");
}

int main(int argc, char **argv)
{
    /* die with the parent: SIGTERM (handled below like a Ctrl-C) when it exits. The
     * parent may have died before prctl() took effect; then we have been re-parented
     * already, which the getppid() checks below catch. */
    pid_t ppid_at_start = getppid();
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (getppid() != ppid_at_start) return 1;
    pid_t parent_pid = 0;
    /* defaults: configs/rig_default.toml */
    plant_params_t p = {.R = 8.0, .L = 0.0085, .J = 5.2245e-5, .B = 1.0e-5, .K = 0.05, .Ka = 5.0,
                        .Vmax = 13.0, .N = 30.0, .Kt = 0.026, .Kpot = 0.5, .pos_offset = -4.0,
                        .noise_tacho = 0.010, .noise_pos = 0.004, .Tc = 0.0, .closed = 0,
                        .kp = 10.0, .kv = 1.0, .seed = 1};
    motor_params_t mp = {.supply = 12.0, .drop = 0.0, .dead_fwd = 0.0, .dead_rev = 0.0, .Ts = 0.0,
                         .backlash = 0.0, .encoder_on_output = 0, .lines = 11.0, .in1_in2 = 0,
                         .brake = 0};
    const char *enc_log_path = NULL;
    const char *fw = NULL, *board = "uno", *dac_log_path = NULL, *link = NULL, *boot = NULL;
    const char *eeprom_path = NULL;
    double speed = 1.0;
    static struct option opts[] = {
        {"fw", 1, 0, 'f'}, {"board", 1, 0, 'b'}, {"speed", 1, 0, 's'}, {"dac-log", 1, 0, 'd'},
        {"link", 1, 0, 'l'}, {"loop", 1, 0, 'o'}, {"kp", 1, 0, 1}, {"kv", 1, 0, 2},
        {"R", 1, 0, 3}, {"L", 1, 0, 4}, {"J", 1, 0, 5}, {"B", 1, 0, 6}, {"K", 1, 0, 7},
        {"Ka", 1, 0, 8}, {"Vmax", 1, 0, 9}, {"N", 1, 0, 10}, {"Kt", 1, 0, 11}, {"Kpot", 1, 0, 12},
        {"pos-offset", 1, 0, 13}, {"noise-tacho", 1, 0, 14}, {"noise-pos", 1, 0, 15},
        {"Tc", 1, 0, 16}, {"seed", 1, 0, 17}, {"parent-pid", 1, 0, 18}, {"help", 0, 0, 'h'},
        {"rig", 1, 0, 30}, {"supply", 1, 0, 31}, {"drop", 1, 0, 32}, {"dead-fwd", 1, 0, 33},
        {"dead-rev", 1, 0, 34}, {"Ts", 1, 0, 35}, {"backlash", 1, 0, 36},
        {"encoder-on-output", 0, 0, 37}, {"lines", 1, 0, 38}, {"in1-in2", 0, 0, 39},
        {"brake", 0, 0, 40}, {"enc-log", 1, 0, 41}, {"current-v-per-a", 1, 0, 42},
        {"current-zero", 1, 0, 43}, {"index", 0, 0, 44}, {"miss-edges", 1, 0, 45},
        {"estop-at", 1, 0, 46}, {"bootloader", 1, 0, 47},
        {"eeprom", 1, 0, 48}, {"stuck-adc", 1, 0, 49},
        {0, 0, 0, 0}};
    int c;
    while ((c = getopt_long_only(argc, argv, "", opts, NULL)) != -1) {
        double v = optarg ? atof(optarg) : 0;
        switch (c) {
        case 'f': fw = optarg; break;
        case 'b': board = optarg; break;
        case 's': speed = v; break;
        case 'd': dac_log_path = optarg; break;
        case 'l': link = optarg; break;
        case 'o':
            loop_forced = !strcmp(optarg, "closed") ? 1 : !strcmp(optarg, "open") ? 0 : -1;
            break;
        case 1: p.kp = v; break;
        case 2: p.kv = v; break;
        case 3: p.R = v; break;
        case 4: p.L = v; break;
        case 5: p.J = v; break;
        case 6: p.B = v; break;
        case 7: p.K = v; break;
        case 8: p.Ka = v; break;
        case 9: p.Vmax = v; break;
        case 10: p.N = v; break;
        case 11: p.Kt = v; break;
        case 12: p.Kpot = v; break;
        case 13: p.pos_offset = v; break;
        case 14: p.noise_tacho = v; break;
        case 15: p.noise_pos = v; break;
        case 16: p.Tc = v; break;
        case 17: p.seed = (uint64_t)strtoull(optarg, NULL, 10); break;
        case 18: parent_pid = (pid_t)atol(optarg); break;
        case 30:
            if (!strcmp(optarg, "hbridge")) rig_hbridge = 1;
            else if (strcmp(optarg, "ms150")) { usage(); return 2; }
            break;
        case 31: mp.supply = v; break;
        case 32: mp.drop = v; break;
        case 33: mp.dead_fwd = v; break;
        case 34: mp.dead_rev = v; break;
        case 35: mp.Ts = v; break;
        case 36: mp.backlash = v; break;
        case 37: mp.encoder_on_output = 1; break;
        case 38: mp.lines = v; break;
        case 39: mp.in1_in2 = 1; break;
        case 40: mp.brake = 1; break;
        case 41: enc_log_path = optarg; break;
        case 42: sense_v_per_a = v; break;
        case 43: sense_zero_v = v; break;
        case 44: idx_on = 1; break;
        case 45: miss_every = atol(optarg); break;
        case 46: estop_at = atof(optarg); break;
        case 47: boot = optarg; break;
        case 48: eeprom_path = optarg; break;
        case 49: stuck_adc = atoi(optarg); break;
        default: usage(); return 2;
        }
    }
    if ((!fw && !boot) || (strcmp(board, "uno") && strcmp(board, "nano") && strcmp(board, "mega")) || p.L <= 0 ||
        p.J <= 0 || p.N == 0 || (rig_hbridge && (mp.supply <= 0 || mp.lines <= 0)) || miss_every < 0) {
        usage();
        return 2;
    }
    if (parent_pid > 0 && getppid() != parent_pid) return 1;   /* its parent is gone already */
    if (loop_forced >= 0) p.closed = loop_forced;
    plant_init(&plant, &p);
    lr_decoder_init(&snoop);

    /* simavr and uart_pty chat on stdout; stdout is reserved for the pty path */
    fflush(stdout);
    int out_fd = dup(1);
    dup2(2, 1);

    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    if (fw && elf_read_firmware(fw, &f) != 0) {
        fprintf(stderr, "labrig-emu: cannot read firmware %s\n", fw);
        return 1;
    }
    const char *mcu = !strcmp(board, "mega") ? "atmega2560" : "atmega328p";
    avr = avr_make_mcu_by_name(mcu);
    if (!avr) { fprintf(stderr, "labrig-emu: simavr has no %s\n", mcu); return 1; }
    avr_init(avr);
    f.frequency = 16000000;
    if (fw) avr_load_firmware(avr, &f);
    uint8_t *eeprom = NULL;   /* the chip's EEPROM bytes (simavr's own buffer) */
    size_t eeprom_size = !strcmp(board, "mega") ? 4096 : 1024;
    if (eeprom_path) {   /* the EEPROM as the board kept it (erased when the file is new) */
        /* size 0 and no buffer: simavr hands out its own (its ioctl returns -1 either way,
         * and some versions refuse a copy of the whole EEPROM) */
        avr_eeprom_desc_t d = {.ee = NULL, .offset = 0, .size = 0};
        avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &d);
        eeprom = d.ee;
        FILE *fe = eeprom ? fopen(eeprom_path, "rb") : NULL;
        if (fe) {
            if (fread(eeprom, 1, eeprom_size, fe) == 0 && ferror(fe))
                fprintf(stderr, "labrig-emu: cannot read %s\n", eeprom_path);
            fclose(fe);
        }
        if (!eeprom) fprintf(stderr, "labrig-emu: simavr gives no EEPROM: --eeprom ignored\n");
    }
    if (boot) {
        /* a bootloader in its section, run from reset as the BOOTRST fuse does: avrdude
         * writes the application through it (SPM) over the pty, as on the bench */
        uint32_t size = 0, base = 0;
        uint8_t *img = read_ihex_file(boot, &size, &base);
        if (!img || base + size > avr->flashend + 1) {
            fprintf(stderr, "labrig-emu: cannot read bootloader %s\n", boot);
            return 1;
        }
        memcpy(avr->flash + base, img, size);
        free(img);
        avr->pc = base;
        avr->codeend = avr->flashend;
    }
    avr->frequency = 16000000;
    avr->vcc = avr->avcc = avr->aref = 5000;   /* mV: the ADC scales by them */
    avr->log = LOG_ERROR;

    if (dac_log_path && !(dac_log = fopen(dac_log_path, "w"))) {
        fprintf(stderr, "labrig-emu: cannot write %s: %s\n", dac_log_path, strerror(errno));
        return 1;
    }
    int mega = !strcmp(board, "mega");
    if (rig_hbridge) {
        if (enc_log_path && !(enc_log = fopen(enc_log_path, "w"))) {
            fprintf(stderr, "labrig-emu: cannot write %s: %s\n", enc_log_path, strerror(errno));
            return 1;
        }
        mp.R = p.R; mp.L = p.L; mp.J = p.J; mp.B = p.B; mp.K = p.K; mp.N = p.N; mp.Tc = p.Tc;
        motor_init(&motor, &mp);
        /* hal_hbridge.inc's pins: OC1A/OC1B, encoder A/B on INT0/INT1 (Mega INT4/INT5) */
        pin_a_bit = mega ? 5 : 1;
        pin_b_bit = mega ? 6 : 2;
        enc_port = mega ? 'E' : 'D';
        enc_a_bit = mega ? 4 : 2;
        enc_b_bit = mega ? 5 : 3;
        encoder_pins(0);
        /* the index: a pin-change interrupt on the Uno (D4 = PD4), INT2 on the Mega
         * (D19 = PD2); low at reset (the shaft rests half a turn from its mark) */
        idx_bit = mega ? 2 : 4;
        idx_per_turn = llround(4.0 * mp.lines);
        idx_at = 4 * (idx_per_turn / 8);
        if (idx_on) avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), idx_bit), 0);
        avr_cycle_timer_register(avr, 16, motor_tick, NULL);
        if (sense_v_per_a > 0)
            avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER),
                                    adc_trigger_current, NULL);
    } else {
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_trigger, NULL);
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_OUTPUT), spi_out, NULL);
        int cs = mega ? 0 : 2;   /* Mega D53 = PB0, Uno D10 = PB2 */
        avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), cs), cs_pin, NULL);
    }
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), uart_in, NULL);
    if (estop_at >= 0.0) {
        estop_port = mega ? 'H' : 'D';
        estop_bit = mega ? 4 : 7;
        avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(estop_port), estop_bit), 0);
        avr_cycle_timer_register(avr, 16000, estop_hold, NULL);
    }

    uart_pty_init(avr, &pty);
    uart_pty_connect(&pty, '0');
    {   /* the line between them judges the speed (line_garbles) */
        avr_irq_t *src = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT);
        avr_irq_t *dst = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
        avr_unconnect_irq(src, pty.irq + IRQ_UART_PTY_BYTE_IN);
        avr_unconnect_irq(pty.irq + IRQ_UART_PTY_BYTE_OUT, dst);
        avr_irq_register_notify(src, chip_to_host, NULL);
        avr_irq_register_notify(pty.irq + IRQ_UART_PTY_BYTE_OUT, host_to_chip, NULL);
        /* the chip's bytes go out through flush_to_host; uart_pty's thread only reads the
         * master after select() says it can, so non-blocking costs it nothing */
        fcntl(pty.pty.s, F_SETFL, fcntl(pty.pty.s, F_GETFL) | O_NONBLOCK);
    }
    if (link) {
        unlink(link);
        if (symlink(pty.pty.slavename, link) != 0)
            fprintf(stderr, "labrig-emu: cannot link %s: %s\n", link, strerror(errno));
    }
    fflush(stdout);
    dprintf(out_fd, "%s\n", pty.pty.slavename);
    close(out_fd);

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    struct timespec t0, tn;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    uint64_t c0 = avr->cycle;
    avr_cycle_count_t flushed_at = avr->cycle;
    double behind_said = 0.0;   /* the largest lag behind real time reported so far, s */
    int state = cpu_Running;
    while (!stop_flag && state != cpu_Done && state != cpu_Crashed) {
        for (int k = 0; k < 2000 && state != cpu_Done && state != cpu_Crashed; k++)
            state = avr_run(avr);
        /* at most every 1 ms of the chip's time (uart_pty polled every 500 us), sooner
         * when a frame's worth is waiting: a reply is late by under 1 ms, not a syscall
         * per byte */
        if (to_host_w - to_host_r >= 96 || avr->cycle - flushed_at >= 16000
                || to_host_dropped > to_host_dropped_said) {
            flush_to_host();
            flushed_at = avr->cycle;
        }
        if (speed > 0) {
            clock_gettime(CLOCK_MONOTONIC, &tn);
            double wall = (tn.tv_sec - t0.tv_sec) + (tn.tv_nsec - t0.tv_nsec) * 1e-9;
            double ahead = (double)(avr->cycle - c0) / avr->frequency / speed - wall;
            if (ahead > 0.001) {
                struct timespec ts = {(time_t)ahead, (long)((ahead - (time_t)ahead) * 1e9)};
                nanosleep(&ts, NULL);
            } else if (-ahead > behind_said + 0.010) {
                /* a machine too busy for a real-time board: say by how much, so a test
                 * that fails on timing can tell the host's load from the firmware */
                behind_said = -ahead;
                fprintf(stderr, "labrig-emu: behind real time by %.0f ms\n", 1e3 * behind_said);
                fflush(stderr);
            }
        }
    }
    if (state == cpu_Crashed) fprintf(stderr, "labrig-emu: firmware crashed\n");
    if (eeprom) {   /* kept for the next start, as the chip keeps it */
        FILE *fe = fopen(eeprom_path, "wb");
        if (!fe || fwrite(eeprom, 1, eeprom_size, fe) != eeprom_size)
            fprintf(stderr, "labrig-emu: cannot keep the EEPROM in %s\n", eeprom_path);
        if (fe) fclose(fe);
    }
    if (link) unlink(link);
    if (dac_log) fclose(dac_log);
    if (enc_log) fclose(enc_log);
    fflush(stderr);
    _exit(state == cpu_Crashed ? 1 : 0);   /* uart_pty_stop() can hang: do not call it */
}

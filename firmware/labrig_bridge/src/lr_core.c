/* labrig bridge core; see lr_core.h and firmware/PROTOCOL.md. */
#include "lr_core.h"
#include "lr_hal.h"

/* Texts live in flash on the AVR (the Uno's 2 kB of RAM is the stack's too): LR_TEXT
 * marks one, LR_TEXT_BYTE reads it */
#ifdef __AVR__
#include <avr/pgmspace.h>
#define LR_TEXT(s) PSTR(s)
#define LR_TEXT_BYTE(p) pgm_read_byte(p)
#else
#define LR_TEXT(s) (s)
#define LR_TEXT_BYTE(p) (*(p))
#endif

typedef struct {
    uint32_t index;
    uint16_t dac, tacho, pos, ref;
} sample_t;

typedef struct {
    uint8_t loop, waveform, n_levels;
    uint16_t kp_q, kd_q;   /* digital loop: duty counts per count, and per count per sample, x256;
                              the board's loop on sensors: DAC counts per pot word, and per
                              tacho word, x256 */
    uint16_t ref_lead, tacho_zero;   /* the board's loop on sensors: lead-in reference, tacho at rest */
    uint16_t rate_hz, dac_zero, dac_min, dac_max, watchdog_ms;
    uint32_t n_samples, lead_in, segment;
    uint16_t levels[LR_MAX_LEVELS];
    uint16_t pieces[LR_MAX_LEVELS - 1];   /* pwl: samples from breakpoint i to i+1 */
} config_t;

static config_t cfg;
static uint8_t board, tx_seq;
static const char *fw_name;
static uint16_t max_rate;
static lr_decoder_t dec;
static lr_counters_t ctr;
static uint32_t last_rx_ms;
/* seq of the START that began the current run: the host retransmits a START whose ACK
 * it missed with the same seq, and that must not restart the experiment */
static uint8_t start_seq, start_seq_valid;

/* shared with the ISRs */
static volatile uint8_t state;
static volatile uint16_t dac_now;
static volatile uint8_t acquiring;
static volatile uint8_t ring_head, ring_tail;
static sample_t ring[LR_RING];
static sample_t cur;
/* waveform generator state, advanced once per tick (no division in the ISR) */
static uint32_t tick_index, lead_left, seg_left;
static uint8_t level_idx;
/* pwl: the piece being played, as a + trunc(d j / L) kept without division per tick
 * (Bresenham: q += step, and one more count whenever acc passes L) */
static int16_t pwl_q, pwl_step, pwl_sign;
/* the digital loop: the count at START (positions are the run's own) and the last one */
static int32_t loop_origin, loop_prev;
static uint16_t ref_now;
static uint16_t pwl_j, pwl_acc, pwl_rem;
/* trips (LIMITS): what is checked at each sample, the allowed ranges, and why the run
 * ended (0: it did not trip); the H-bridge's speed is the count's change per sample */
static uint8_t trip_flags;
static volatile uint8_t tripped;
/* an E-stop seen: no run starts until a ZERO finds the switch closed again */
static volatile uint8_t estop_latched;
static int32_t trip_s_lo, trip_s_hi, trip_p_lo, trip_p_hi;
#if LR_DECODING
static int32_t trip_prev;
static uint32_t trip_prev_index;
static uint8_t trip_primed;
#endif

static void pwl_piece(uint8_t i)
{
    int16_t d = (int16_t)cfg.levels[i + 1] - (int16_t)cfg.levels[i];
    uint16_t L = cfg.pieces[i];
    pwl_q = (int16_t)cfg.levels[i];
    pwl_step = (int16_t)(d / (int16_t)L);
    pwl_rem = (uint16_t)(d < 0 ? -(d % (int16_t)L) : d % (int16_t)L);
    pwl_sign = d < 0 ? -1 : 1;
    pwl_j = 0;
    pwl_acc = 0;
}

/* The next pwl word (the ISR calls it once per sample after the lead-in). */
static uint16_t pwl_next(void)
{
    if (level_idx + 1 >= cfg.n_levels) return cfg.levels[cfg.n_levels - 1];  /* held */
    uint16_t w = (uint16_t)pwl_q;
    if (++pwl_j >= cfg.pieces[level_idx]) {
        level_idx++;
        if (level_idx + 1 < cfg.n_levels) pwl_piece(level_idx);
        return w;
    }
    pwl_q += pwl_step;
    pwl_acc += pwl_rem;
    if (pwl_acc >= cfg.pieces[level_idx]) {
        pwl_acc -= cfg.pieces[level_idx];
        pwl_q += pwl_sign;
    }
    return w;
}

static uint16_t lim_lo(void) { return (uint16_t)(LR_DAC_ZERO - LR_FW_LIMIT_COUNTS); }
static uint16_t lim_hi(void) { return (uint16_t)(LR_DAC_ZERO + LR_FW_LIMIT_COUNTS); }

/* The only path to the DAC: every word is clamped to the configured and the firmware
 * limits, whatever called it. */
static void dac_set(uint16_t w)
{
    uint16_t lo = cfg.dac_min > lim_lo() ? cfg.dac_min : lim_lo();
    uint16_t hi = cfg.dac_max < lim_hi() ? cfg.dac_max : lim_hi();
    if (w < lo) w = lo;
    if (w > hi) w = hi;
    dac_now = w;
    hal_dac_write(w);
}

static void send(uint8_t type, const uint8_t *body, uint16_t len)
{
    static uint8_t wire[LR_MAX_WIRE];   /* main loop only: static keeps it off the stack */
    size_t n = lr_frame_build(type, tx_seq++, body, len, wire);
    if (n) hal_tx_write(wire, (uint16_t)n);
}

static void send_error(uint8_t code, const char *text)
{
    uint8_t b[48];
    uint16_t n = 1;
    b[0] = code;
    char c;
    while ((c = (char)LR_TEXT_BYTE(text)) && n < sizeof b) { b[n++] = (uint8_t)c; text++; }
    send(LR_ERROR, b, n);
}

static void send_ack(uint8_t type, uint8_t seq)
{
    uint8_t b[2] = {type, seq};
    send(LR_ACK, b, 2);
}

void lr_core_send_hello(void)
{
    uint8_t b[80];
    b[0] = LR_PROTOCOL_VERSION;
    b[1] = board;
    /* capabilities: square|step|staircase|constant|pwl, and on the MS150 its own loop */
    lr_put16(b + 2, LR_RIG_KIND == 1 ? 0x001F | LR_CAP_BOARD_LOOP : 0x001F);
    lr_put16(b + 4, max_rate);
    b[6] = LR_BATCH; b[7] = LR_DAC_BITS; b[8] = 10; b[9] = LR_ADC_CHANNELS; b[10] = LR_MAX_LEVELS;
    lr_put16(b + 11, LR_DAC_ZERO);
    lr_put16(b + 13, lim_lo());
    lr_put16(b + 15, lim_hi());
    lr_put16(b + 17, LR_WATCHDOG_MS_DEFAULT);
    /* protocol 2: the build's rig */
    b[19] = LR_RIG_KIND;
    lr_put32(b + 20, LR_TIMER_HZ);
    b[24] = LR_RIG_FLAGS; b[25] = LR_DECODING; b[26] = LR_PWM_BITS;
    lr_put16(b + 27, LR_MIN_RATE_HZ);
    uint16_t n = 29;
    char c;
    for (const char *p = fw_name; (c = (char)LR_TEXT_BYTE(p)) && n < sizeof b; p++) b[n++] = (uint8_t)c;
    send(LR_HELLO, b, n);
}

/* Stop sampling and put the output at 0 V; safe from the main loop at any time. */
static void stop_and_zero(void)
{
    hal_timer_stop();
    uint8_t s = hal_lock();
    dac_set(cfg.dac_zero);
    if (state == LR_STATE_RUNNING || state == LR_STATE_FINISHING) state = LR_STATE_CONFIGURED;
    ring_tail = ring_head;
    acquiring = 0;
    hal_unlock(s);
}

void lr_core_init(uint8_t board_id, const char *fw_id, uint16_t max_rate_hz)
{
    board = board_id; fw_name = fw_id; max_rate = max_rate_hz;
    cfg.dac_zero = LR_DAC_ZERO; cfg.dac_min = lim_lo(); cfg.dac_max = lim_hi();
    cfg.watchdog_ms = LR_WATCHDOG_MS_DEFAULT;
    state = LR_STATE_IDLE;
    start_seq_valid = 0;
    lr_decoder_init(&dec);
    dac_set(LR_DAC_ZERO);   /* 0 V at reset, before anything else can happen */
    last_rx_ms = hal_millis();
}

static int configure(const uint8_t *b, uint16_t len)
{
    if (len < LR_CONFIGURE_FIXED) return LR_ERR_BAD_FRAME;
    config_t c;
    c.loop = b[0]; c.waveform = b[1];
    c.rate_hz = lr_get16(b + 2);
    c.n_samples = lr_get32(b + 4);
    c.lead_in = lr_get32(b + 8);
    c.segment = lr_get32(b + 12);
    c.dac_zero = lr_get16(b + 16);
    c.dac_min = lr_get16(b + 18);
    c.dac_max = lr_get16(b + 20);
    c.watchdog_ms = lr_get16(b + 22);
    /* b[24..27]: loop gains: on a digital loop the PD's (Q8.8, duty counts per count and
     * per count per sample); on the MS150, for the record only (the rig's patch panel
     * closes its loop, at the gains the rig file states) */
    c.kp_q = lr_get16(b + 24);
    c.kd_q = lr_get16(b + 26);
    c.n_levels = b[28];
    /* pwl: the breakpoints' words, then the n-1 piece lengths in samples */
    uint16_t extra = c.waveform == LR_WAVE_PWL && c.n_levels ? 2u * (c.n_levels - 1u) : 0u;
    uint16_t tail = c.loop == LR_LOOP_BOARD ? LR_BOARD_LOOP_TAIL : 0u;
    if (c.n_levels < 1 || c.n_levels > LR_MAX_LEVELS ||
        len != LR_CONFIGURE_FIXED + 2u * c.n_levels + extra + tail)
        return LR_ERR_BAD_FRAME;
    /* the board's own loop on its sensors: the MS150 build (the H-bridge's closed loop is
     * always its own, on the count) */
    if (c.loop > (LR_RIG_KIND == 1 ? LR_LOOP_BOARD : LR_LOOP_CLOSED) ||
        c.waveform > LR_WAVE_PWL || c.n_samples == 0 || c.watchdog_ms < 50)
        return LR_ERR_BAD_CONFIG;
    c.ref_lead = c.tacho_zero = 0;
    if (tail) {
        c.ref_lead = lr_get16(b + len - 4);
        c.tacho_zero = lr_get16(b + len - 2);
    }
    if (c.waveform == LR_WAVE_PWL) {
        if (c.n_levels < 2) return LR_ERR_BAD_CONFIG;
        for (uint8_t i = 0; i + 1 < c.n_levels; i++) {
            c.pieces[i] = lr_get16(b + LR_CONFIGURE_FIXED + 2 * c.n_levels + 2 * i);
            if (c.pieces[i] == 0 || c.pieces[i] > 0x7FFF) return LR_ERR_BAD_CONFIG;
        }
    }
    if ((c.waveform == LR_WAVE_SQUARE || c.waveform == LR_WAVE_STAIRCASE) && c.segment == 0)
        return LR_ERR_BAD_CONFIG;
    if (c.waveform == LR_WAVE_SQUARE && c.n_levels != 2) return LR_ERR_BAD_CONFIG;
    if (c.rate_hz < LR_MIN_RATE_HZ || c.rate_hz > max_rate || LR_TIMER_HZ % c.rate_hz)
        return LR_ERR_RATE;
    if (c.dac_min > c.dac_max || c.dac_min < lim_lo() || c.dac_max > lim_hi() ||
        c.dac_zero < c.dac_min || c.dac_zero > c.dac_max)
        return LR_ERR_LIMIT;
    for (uint8_t i = 0; i < c.n_levels; i++) {
        c.levels[i] = lr_get16(b + LR_CONFIGURE_FIXED + 2 * i);
        /* a digital loop's levels are references in counts, the board's loop on sensors'
         * pot words; their output is clamped below */
        if (!(LR_DIGITAL_LOOP && c.loop == LR_LOOP_CLOSED) && c.loop != LR_LOOP_BOARD &&
            (c.levels[i] < c.dac_min || c.levels[i] > c.dac_max))
            return LR_ERR_LIMIT;
    }
    cfg = c;
    return 0;
}

static void handle(const lr_frame_t *f)
{
    int err;
    switch (f->type) {
    case LR_HELLO_REQ:
        lr_core_send_hello();
        break;
    case LR_HEARTBEAT:
        break;
    case LR_CONFIGURE:
        start_seq_valid = 0;
        if (state == LR_STATE_RUNNING || state == LR_STATE_FINISHING) {
            send_error(LR_ERR_BUSY, LR_TEXT("configure while running"));
            break;
        }
        err = configure(f->body, f->body_len);
        if (err) {
            state = LR_STATE_IDLE;
            send_error((uint8_t)err, err == LR_ERR_LIMIT ? LR_TEXT("level beyond output limit") :
                       err == LR_ERR_RATE ? LR_TEXT("sample rate out of range") : LR_TEXT("bad configure"));
        } else {
            uint8_t s = hal_lock();
            dac_set(cfg.dac_zero);
            hal_unlock(s);
            trip_flags = 0;   /* a run's limits come after its CONFIGURE */
            state = LR_STATE_CONFIGURED;
            send_ack(f->type, f->seq);
        }
        break;
    case LR_LIMITS:
        if (state == LR_STATE_RUNNING || state == LR_STATE_FINISHING) {
            send_error(LR_ERR_BUSY, LR_TEXT("already running"));
            break;
        }
        if (f->body_len != LR_LIMITS_LEN) {
            send_error(LR_ERR_BAD_FRAME, LR_TEXT("bad limits"));
            break;
        }
        {
            int32_t s_lo = (int32_t)lr_get32(f->body + 1), s_hi = (int32_t)lr_get32(f->body + 5);
            int32_t p_lo = (int32_t)lr_get32(f->body + 9), p_hi = (int32_t)lr_get32(f->body + 13);
            if ((f->body[0] & (uint8_t)~(LR_TRIP_SPEED | LR_TRIP_POSITION | LR_TRIP_ESTOP)) || s_lo > s_hi ||
                p_lo > p_hi) {
                send_error(LR_ERR_BAD_CONFIG, LR_TEXT("bad limits"));
                break;
            }
            uint8_t s = hal_lock();
            trip_flags = f->body[0];
            trip_s_lo = s_lo; trip_s_hi = s_hi; trip_p_lo = p_lo; trip_p_hi = p_hi;
            hal_unlock(s);
        }
        send_ack(f->type, f->seq);
        break;
    case LR_BOARD_ID:
        /* the id a host gave this board once (kept across resets and flashes that keep
         * the EEPROM): a given id is never replaced, so a bench's board keeps its name */
        if (f->body_len != 0 && f->body_len != 4) {
            send_error(LR_ERR_BAD_FRAME, LR_TEXT("bad board id"));
            break;
        }
        if (f->body_len == 4 && hal_id_read() == 0 && lr_get32(f->body) != 0) {
            if (state == LR_STATE_RUNNING || state == LR_STATE_FINISHING) {
                send_error(LR_ERR_BUSY, LR_TEXT("already running"));
                break;
            }
            hal_id_write(lr_get32(f->body));
        }
        {
            uint8_t b[4];
            lr_put32(b, hal_id_read());
            send(LR_ID, b, 4);
        }
        break;
    case LR_START:
        if (start_seq_valid && f->seq == start_seq) {
            /* a retransmission: acknowledge again, never restart (even after DONE) */
            send_ack(f->type, f->seq);
            break;
        }
        if (estop_latched || ((trip_flags & LR_TRIP_ESTOP) && hal_estop())) {
            estop_latched = 1;
            send_error(LR_ERR_TRIP, LR_TEXT("E-stop latched: close it, then start again"));
            break;
        }
        if (state != LR_STATE_CONFIGURED) {
            send_error(state == LR_STATE_IDLE ? LR_ERR_NOT_CONFIGURED : LR_ERR_BUSY,
                       state == LR_STATE_IDLE ? LR_TEXT("start before configure") : LR_TEXT("already running"));
            break;
        }
        {
            uint8_t s = hal_lock();
            tick_index = 0; lead_left = cfg.lead_in; seg_left = cfg.segment; level_idx = 0;
            if (cfg.waveform == LR_WAVE_PWL) pwl_piece(0);
            loop_origin = hal_position();
            loop_prev = 0;
            ref_now = LR_REF_ZERO;
            ring_head = ring_tail = 0; acquiring = 0;
            ctr.sample_overruns = ctr.ring_overflows = 0;
            tripped = 0;
#if LR_DECODING
            trip_primed = 0;
#endif
            hal_index_reset();          /* a run's index pulses are its own */
            state = LR_STATE_RUNNING;
            hal_unlock(s);
        }
        start_seq = f->seq;
        start_seq_valid = 1;
        /* the timer before the ack: the first sample is one period after START (where the
         * count's origin was taken) however long the ack takes to leave (a host that drains
         * its port late holds the UART); the ack still goes first, since only this loop
         * sends the ring's SAMPLES */
        hal_timer_start(cfg.rate_hz);
        send_ack(f->type, f->seq);
        break;
    case LR_STOP:
    case LR_ZERO:
        start_seq_valid = 0;
        stop_and_zero();
        if (f->type == LR_ZERO && !hal_estop()) estop_latched = 0;   /* closed again */
        send_ack(f->type, f->seq);
        break;
    case LR_STATUS_REQ: {
        uint8_t b[29];
        lr_put32(b, ctr.samples_sent);
        lr_put32(b + 4, dec.frames_ok);
        lr_put32(b + 8, dec.crc_errors);
        lr_put32(b + 12, dec.framing_errors + ctr.rx_overruns);
        lr_put32(b + 16, ctr.watchdog_trips);
        lr_put32(b + 20, ctr.sample_overruns + ctr.ring_overflows);
        b[24] = state;
        lr_put16(b + 25, dac_now);
        lr_put16(b + 27, hal_encoder_faults());
        send(LR_STATUS, b, 29);
        break;
    }
#ifdef LR_TEST_HOOKS
    case 0x7E:   /* test builds only: the main loop stops, as a hang would (ISRs run on) */
        send_ack(f->type, f->seq);
        for (;;) { }
#endif
    default:
        send_error(LR_ERR_BAD_FRAME, LR_TEXT("unknown message type"));
    }
}

/* A limit crossed (ISR): 0 V at once, the run over; the main loop sends the fault once
 * the samples before it are out */
static void trip(uint8_t why)
{
    hal_timer_stop();
    dac_set(cfg.dac_zero);
    tripped = why;
    state = LR_STATE_FINISHING;
}

/* Timer ISR: one sample period. */
void lr_core_tick(void)
{
    if (state != LR_STATE_RUNNING) return;
    if ((trip_flags & LR_TRIP_ESTOP) && hal_estop()) {   /* before this sample's output */
        estop_latched = 1;
        trip(LR_TRIP_ESTOP);
        return;
    }
    if (tick_index >= cfg.n_samples) {
        hal_timer_stop();
        dac_set(cfg.dac_zero);      /* end of experiment: back to 0 V */
        state = LR_STATE_FINISHING;
        return;
    }
    uint16_t w;
    uint8_t in_lead = lead_left != 0;   /* this sample is the lead-in's (before the decrement) */
    if (lead_left) {
        lead_left--;
        w = cfg.dac_zero;
    } else if (cfg.waveform == LR_WAVE_PWL) {
        w = pwl_next();
    } else {
        w = cfg.levels[level_idx];
        if (cfg.segment && --seg_left == 0) {
            seg_left = cfg.segment;
            if (cfg.waveform == LR_WAVE_SQUARE) level_idx ^= 1;
            else if (cfg.waveform == LR_WAVE_STAIRCASE && level_idx + 1 < cfg.n_levels) level_idx++;
        }
    }
#if LR_DIGITAL_LOOP
    if (cfg.loop == LR_LOOP_CLOSED) {
        /* the PD on the count, at this sample: out = kp (ref - x) - kd (x - x_prev), in duty
         * counts (Q8.8 gains), applied now and clamped to the limits by dac_set; during the
         * lead-in the reference is the run's start */
        ref_now = in_lead ? LR_REF_ZERO : w;
        int32_t x = hal_position() - loop_origin;
        int32_t e = (int32_t)ref_now - LR_REF_ZERO - x, v = x - loop_prev;
        loop_prev = x;
        if (e > 32767) e = 32767;
        if (e < -32767) e = -32767;
        if (v > 32767) v = 32767;
        if (v < -32767) v = -32767;
        int32_t out = (int32_t)(((int64_t)cfg.kp_q * e - (int64_t)cfg.kd_q * v) >> 8);   /* floor */
        int32_t word = (int32_t)cfg.dac_zero + out;
        w = word < 0 ? 0 : word > 0xFFFF ? 0xFFFF : (uint16_t)word;
    }
#endif
#if LR_RIG_KIND == 1
    uint8_t board_loop = cfg.loop == LR_LOOP_BOARD;
#else
    const uint8_t board_loop = 0;   /* (the H-bridge's closed loop is its PD above) */
    (void)in_lead;
#endif
    if (board_loop) {
        /* the board's loop on its sensors: this tick sets the reference (the lead-in's is
         * the one the host gave); the output follows when this sample's words are in */
        ref_now = in_lead ? cfg.ref_lead : w;
    }
    if (acquiring) {
        /* the previous conversions are still running: this period is lost (the host
         * sees a gap in the sample index); the waveform keeps its timing (a board's loop
         * holds its output: nothing new was read) */
        ctr.sample_overruns++;
        if (!board_loop) dac_set(w);
        tick_index++;
        return;
    }
    if (!board_loop) dac_set(w);
    cur.index = tick_index++;
    cur.dac = dac_now;
    cur.ref = ref_now;   /* a digital loop's reference word; the HAL may overwrite it */
    acquiring = 1;
    hal_adc_start();
}

/* The sample's speed and position against the run's limits (ISR). */
static void check_limits(uint16_t tacho, uint16_t pos)
{
    uint8_t why = 0;
#if LR_DECODING
    /* the count, as the HAL splits it over the tacho and pos words */
    int32_t x = (int32_t)((uint32_t)tacho | ((uint32_t)pos << 16)) - loop_origin;
    if (trip_primed && cur.index == trip_prev_index + 1) {
        int32_t v = x - trip_prev;
        if ((trip_flags & LR_TRIP_SPEED) && (v < trip_s_lo || v > trip_s_hi)) why = LR_TRIP_SPEED;
    }
    trip_prev = x; trip_prev_index = cur.index; trip_primed = 1;
#else
    int32_t v = tacho, x = pos;
    if ((trip_flags & LR_TRIP_SPEED) && (v < trip_s_lo || v > trip_s_hi)) why = LR_TRIP_SPEED;
#endif
    if (!why && (trip_flags & LR_TRIP_POSITION) && (x < trip_p_lo || x > trip_p_hi))
        why = LR_TRIP_POSITION;
    if (why) trip(why);
}

/* ADC ISR: the three channels of the current sample are in. */
void lr_core_sample_done(uint16_t tacho, uint16_t pos, uint16_t ref)
{
    if (!acquiring) return;
    acquiring = 0;
    /* a limit first: the sample that trips is the run's last, its output 0 V */
    if (trip_flags && state == LR_STATE_RUNNING) check_limits(tacho, pos);
#if LR_RIG_KIND == 1
    if (cfg.loop == LR_LOOP_BOARD) {
        if (state == LR_STATE_RUNNING) {
            /* the board's loop on its sensors, on this sample's words, applied now (the
             * conversions' ~0.2 ms after the tick) and held to the next sample:
             * out = kp_q (ref - pos) - kd_q (tacho - tacho at rest), Q8.8 DAC counts; words
             * are 10 bits, so 32 bits hold it */
            int32_t e = (int32_t)ref_now - (int32_t)pos;
            int32_t v = (int32_t)tacho - (int32_t)cfg.tacho_zero;
            int32_t out = ((int32_t)cfg.kp_q * e - (int32_t)cfg.kd_q * v) >> 8;   /* floor */
            int32_t word = (int32_t)cfg.dac_zero + out;
            dac_set(word < 0 ? 0 : word > 0xFFFF ? 0xFFFF : (uint16_t)word);
        }
        cur.dac = dac_now;
        ref = ref_now;   /* the reference it used, not the A2 input */
    }
#endif
    uint8_t next = (uint8_t)((ring_head + 1) & (LR_RING - 1));
    if (next == ring_tail) ctr.ring_overflows++;
    else {
        cur.tacho = tacho; cur.pos = pos; cur.ref = ref;
        ring[ring_head] = cur;
        ring_head = next;
    }
}

void lr_core_rx_overrun(void) { ctr.rx_overruns++; }

static void send_samples(uint8_t finishing)
{
    for (;;) {
        uint8_t head = ring_head, tail = ring_tail;
        uint8_t avail = (uint8_t)((head - tail) & (LR_RING - 1));
        if (avail == 0) return;
        /* a frame holds consecutive indices only */
        uint8_t n = 1;
        while (n < avail && n < LR_BATCH &&
               ring[(tail + n) & (LR_RING - 1)].index == ring[tail].index + n)
            n++;
        if (n < LR_BATCH && n == avail && !finishing) return;  /* wait for a full batch */
        /* worst case of a full SAMPLES frame on the wire; else keep polling RX instead */
        if (hal_tx_free() < 4 + 5 + LR_BATCH * LR_SAMPLE_BYTES + 3) return;
        uint8_t b[5 + LR_BATCH * LR_SAMPLE_BYTES];
        lr_put32(b, ring[tail].index);
        b[4] = n;
        for (uint8_t i = 0; i < n; i++) {
            const sample_t *s = &ring[(tail + i) & (LR_RING - 1)];
            uint8_t *p = b + 5 + i * LR_SAMPLE_BYTES;
            lr_put16(p, s->dac); lr_put16(p + 2, s->tacho);
            lr_put16(p + 4, s->pos); lr_put16(p + 6, s->ref);
        }
        ring_tail = (uint8_t)((tail + n) & (LR_RING - 1));
        send(LR_SAMPLES, b, (uint16_t)(5 + n * LR_SAMPLE_BYTES));
        ctr.samples_sent += n;
    }
}

/* An index pulse of this run, as it came (the latest, if two came between two polls:
 * the pulse number says how many) */
static void send_index(void)
{
    if (hal_tx_free() < 4 + 10 + 3) return;   /* its worst case on the wire; next poll */
    int32_t count;
    uint32_t sample;
    uint16_t pulses;
    if (!hal_index_take(&count, &sample, &pulses)) return;
    uint8_t b[10];
    lr_put32(b, sample);
    lr_put32(b + 4, (uint32_t)count);
    lr_put16(b + 8, pulses);
    send(LR_INDEX, b, 10);
}

void lr_core_poll(void)
{
    int c;
    lr_frame_t f;
    /* bounded so a flood of input cannot starve the sender */
    for (uint8_t k = 0; k < 64 && (c = hal_rx_read()) >= 0; k++) {
        if (lr_decoder_feed(&dec, (uint8_t)c, &f)) {
            last_rx_ms = hal_millis();
            handle(&f);
        }
    }
    uint8_t st = state;
    if (st == LR_STATE_RUNNING || st == LR_STATE_FINISHING) send_index();
    if (st == LR_STATE_RUNNING) {
        send_samples(0);
    } else if (st == LR_STATE_FINISHING && !acquiring) {
        send_samples(1);
        if (ring_head == ring_tail) {
            if (tripped) {
                /* (short texts: every string sits in the Uno's 2 kB of RAM) */
                send_error(LR_ERR_TRIP, tripped == LR_TRIP_SPEED ? LR_TEXT("over-speed")
                           : tripped == LR_TRIP_ESTOP ? LR_TEXT("E-stop")
                           : LR_TEXT("position limit"));
            } else {
                uint8_t b[8];
                lr_put32(b, cfg.n_samples);
                lr_put32(b + 4, ctr.sample_overruns + ctr.ring_overflows);
                send(LR_DONE, b, 8);
            }
            state = LR_STATE_CONFIGURED;
        }
    }
    /* host-silence watchdog: armed while running or while the output is not at zero */
    st = state;
    if ((st == LR_STATE_RUNNING || st == LR_STATE_FINISHING || dac_now != cfg.dac_zero) &&
        (uint32_t)(hal_millis() - last_rx_ms) > cfg.watchdog_ms) {
        stop_and_zero();
        ctr.watchdog_trips++;
        last_rx_ms = hal_millis();
        send_error(LR_ERR_WATCHDOG, LR_TEXT("host silent: output set to 0 V"));
    }
}

uint8_t lr_core_state(void) { return state; }
uint16_t lr_core_reference(void) { return ref_now; }
uint32_t lr_core_sample_index(void) { return tick_index; }
uint16_t lr_core_dac_word(void) { return dac_now; }
const lr_counters_t *lr_core_counters(void) { return &ctr; }
const lr_decoder_t *lr_core_decoder(void) { return &dec; }

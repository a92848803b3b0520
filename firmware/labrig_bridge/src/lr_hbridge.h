/* The H-bridge + quadrature-encoder rig's two pieces of logic, portable C so the host
 * unit tests check them bit for bit: the quadrature decoder (run in the encoder's pin
 * interrupts) and the mapping of a signed drive word to the two bridge inputs. */
#ifndef LR_HBRIDGE_H
#define LR_HBRIDGE_H
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* ---- quadrature decoder ---------------------------------------------------------------
 * state ab = (A << 1) | B. Forward (A leads B) walks 00 -> 10 -> 11 -> 01 -> 00, i.e.
 * ab 0 -> 2 -> 3 -> 1 -> 0. Decoding x4 counts every transition, x2 only those of A
 * (both edges), x1 only A's edge while B is low (00 <-> 10), so a shaft dithering on an
 * edge never drifts. A jump of both channels at once (a missed edge: the shaft outran the
 * interrupt) cannot be decoded: it is counted in `illegal` and the count is unchanged. */
typedef struct {
    volatile int32_t count;     /* signed, never wraps within a run (2^31 counts) */
    volatile uint32_t illegal;  /* undecodable jumps since reset */
    uint8_t state;              /* last ab */
    uint8_t decoding;           /* 4, 2 or 1 */
} lr_quad_t;

/* +1 / -1 / 0 per (old << 2 | new); 2 marks an illegal jump */
static const int8_t LR_QUAD_STEP[16] = {
    /* old 0: to 0,1,2,3 */ 0, -1, +1, 2,
    /* old 1 */             +1, 0, 2, -1,
    /* old 2 */             -1, 2, 0, +1,
    /* old 3 */             2, +1, -1, 0,
};

static inline void lr_quad_init(lr_quad_t *q, uint8_t decoding, uint8_t a, uint8_t b)
{
    q->count = 0;
    q->illegal = 0;
    q->state = (uint8_t)((a ? 2 : 0) | (b ? 1 : 0));
    q->decoding = (decoding == 1 || decoding == 2) ? decoding : 4;
}

/* The pins now read a and b (any nonzero = high); called from the pin interrupts. */
static inline void lr_quad_feed(lr_quad_t *q, uint8_t a, uint8_t b)
{
    uint8_t s = (uint8_t)((a ? 2 : 0) | (b ? 1 : 0));
    uint8_t old = q->state;
    int8_t d = LR_QUAD_STEP[(old << 2) | s];
    q->state = s;
    if (d == 2) { q->illegal++; return; }
    if (d == 0) return;
    if (q->decoding == 2 && !((old ^ s) & 2)) return;           /* a B edge */
    if (q->decoding == 1 && !((old | s) == 2 && !((old & s) & 1)))
        return;                                                  /* not 00 <-> 10 */
    q->count += d;
}

/* ---- index pulse -----------------------------------------------------------------------
 * Once a turn of the encoder's shaft the index channel goes high (most encoders gate it to
 * one quadrature state, A = B = high). Its rising edge latches the count. The decoder is
 * fed the A/B pins first, in the same interrupt: whichever of the index's and the
 * channels' interrupts the chip serves first, the count latched is the count of the state
 * the index marks, the same whichever way the shaft turns. `sample` is the index of the
 * next sample the board takes (the pulse came between samples sample - 1 and sample). */
typedef struct {
    volatile int32_t count;     /* the count at the latest pulse */
    volatile uint32_t sample;   /* the sample it came before */
    volatile uint16_t pulses;   /* pulses since reset (wraps) */
    volatile uint8_t fresh;     /* a pulse not yet taken */
    uint8_t level;              /* the index pin's last level */
} lr_index_t;

static inline void lr_index_reset(lr_index_t *x, uint8_t level)
{
    x->count = 0;
    x->sample = 0;
    x->pulses = 0;
    x->fresh = 0;
    x->level = level ? 1 : 0;
}

/* The pins now read a, b and idx (any nonzero = high); called from the index's interrupt. */
static inline void lr_index_feed(lr_index_t *x, lr_quad_t *q, uint8_t a, uint8_t b, uint8_t idx,
                                 uint32_t sample)
{
    lr_quad_feed(q, a, b);
    if (idx && !x->level) {
        x->count = q->count;
        x->sample = sample;
        x->pulses++;
        x->fresh = 1;
    }
    x->level = idx ? 1 : 0;
}

/* ---- drive word -> bridge inputs -----------------------------------------------------
 * The host sends offset-binary words: word = zero + d, d in [-(top+1), top], where the
 * PWM counts 0..top (top = 2^bits - 1, fast PWM: a compare value c keeps the output high
 * for c + 1 of top + 1 counts). |d| = 0 is off; |d| = n > 0 is the compare value n - 1,
 * a duty of n / (top + 1) of the supply, so volts = d * supply / (top + 1) exactly. */
enum { LR_PIN_LOW = 0, LR_PIN_HIGH = 1, LR_PIN_PWM = 2, LR_PIN_PWM_INV = 3 };
enum { LR_DRIVE_PWM_DIR = 0, LR_DRIVE_IN1_IN2 = 1 };

typedef struct {
    uint16_t compare;   /* the timer's compare value for the pin(s) in a PWM mode */
    uint8_t pin_a;      /* PWM+DIR: the PWM/EN pin; IN1/IN2: IN1 */
    uint8_t pin_b;      /* PWM+DIR: the DIR pin (LOW forward, HIGH reverse); IN1/IN2: IN2 */
} lr_drive_t;

/* The bridge inputs for `word`. PWM+DIR: the PWM pin carries the duty, DIR the sign (the
 * driver decides what its off phase does). IN1/IN2 (TB6612/DRV8833 style): forward is
 * IN1 high / IN2 low; the off phase coasts (both low: fast decay, the PWM on the driven
 * input) or brakes (both high: slow decay, the other input PWM'd inverted). Zero coasts,
 * or brakes when `brake` is set: the motor's terminals at 0 V either way. */
static inline lr_drive_t lr_drive_map(uint16_t word, uint16_t zero, uint16_t top,
                                      uint8_t mode, uint8_t brake)
{
    lr_drive_t o;
    int32_t d = (int32_t)word - (int32_t)zero;
    uint32_t n = (uint32_t)(d < 0 ? -d : d);
    if (n > (uint32_t)top + 1u) n = (uint32_t)top + 1u;
    o.compare = n ? (uint16_t)(n - 1u) : 0u;
    if (mode == LR_DRIVE_PWM_DIR) {
        o.pin_a = n ? LR_PIN_PWM : LR_PIN_LOW;
        o.pin_b = d < 0 ? LR_PIN_HIGH : LR_PIN_LOW;
        return o;
    }
    if (n == 0) {
        o.pin_a = o.pin_b = brake ? LR_PIN_HIGH : LR_PIN_LOW;
        return o;
    }
    uint8_t drive = brake ? LR_PIN_HIGH : LR_PIN_PWM;      /* the input that stays "on" */
    uint8_t other = brake ? LR_PIN_PWM_INV : LR_PIN_LOW;   /* the one that makes the off phase */
    if (d > 0) { o.pin_a = drive; o.pin_b = other; }
    else { o.pin_a = other; o.pin_b = drive; }
    return o;
}

#ifdef __cplusplus
}
#endif
#endif

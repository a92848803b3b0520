/* labrig bridge protocol: CRC-16/CCITT-FALSE, COBS framing, message layout.
 * Portable C99, no allocation; shared by the firmware, the host unit tests and the
 * simavr harness (which snoops CONFIGURE frames). See firmware/PROTOCOL.md. */
#ifndef LR_PROTO_H
#define LR_PROTO_H
#include <stdint.h>
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* 2: HELLO names the build's rig (kind, sample clock, drive, decoding, PWM bits); an
 * H-bridge board's SAMPLES carry the signed 32-bit encoder count in place of two ADC words */
#define LR_PROTOCOL_VERSION 2
/* decoded frame = type + seq + body + crc16; one limit for both directions */
#define LR_MAX_BODY 200
#define LR_MAX_RAW (LR_MAX_BODY + 4)
/* COBS adds one byte per started 254-byte block, plus the 0x00 delimiter */
#define LR_MAX_WIRE (LR_MAX_RAW + LR_MAX_RAW / 254 + 2)
#define LR_BATCH 10        /* samples per SAMPLES frame */
#define LR_SAMPLE_BYTES 8  /* dac, tacho, pos, ref: u16 LE each */
#define LR_MAX_LEVELS 32

/* host -> board */
enum {
    LR_HELLO_REQ = 0x01, LR_CONFIGURE = 0x02, LR_START = 0x03, LR_STOP = 0x04,
    LR_HEARTBEAT = 0x05, LR_STATUS_REQ = 0x06, LR_ZERO = 0x07, LR_LIMITS = 0x08,
    LR_BOARD_ID = 0x09   /* empty: ask the board's id; 4 bytes: give it one, if it has none */
};
/* board -> host */
enum {
    LR_ACK = 0x80, LR_HELLO = 0x81, LR_SAMPLES = 0x82, LR_STATUS = 0x83,
    LR_DONE = 0x84, LR_ERROR = 0x85, LR_INDEX = 0x86,
    LR_ID = 0x87         /* the board's id: u32 LE, kept in EEPROM; 0 = none given yet */
};
/* 2 (the MS150 build, firmware 2.4): the board closes the position loop itself, from the
 * pot and tacho words it samples; the CONFIGURE body then ends with LR_BOARD_LOOP_TAIL
 * bytes: u16 the lead-in's reference word, u16 the tacho's word at rest */
enum { LR_LOOP_OPEN = 0, LR_LOOP_CLOSED = 1, LR_LOOP_BOARD = 2 };
#define LR_BOARD_LOOP_TAIL 4
/* HELLO capability bits: waveforms square|step|staircase|constant|pwl (0x1F), and the
 * board's own loop on its sensors (LR_LOOP_BOARD) */
#define LR_CAP_BOARD_LOOP 0x20
enum { LR_WAVE_CONSTANT = 0, LR_WAVE_SQUARE = 1, LR_WAVE_STEP = 2, LR_WAVE_STAIRCASE = 3,
       LR_WAVE_PWL = 4 };
enum {
    LR_ERR_BAD_FRAME = 1, LR_ERR_BAD_CONFIG = 2, LR_ERR_LIMIT = 3, LR_ERR_NOT_CONFIGURED = 4,
    LR_ERR_BUSY = 5, LR_ERR_WATCHDOG = 6, LR_ERR_RATE = 7, LR_ERR_TRIP = 8
};
/* LIMITS body: flags (bit0 speed, bit1 position), then the speed's and the position's
 * allowed ranges as i32 pairs (MS150: tacho and pot ADC words; H-bridge: counts per
 * sample, and counts from the run's start). A CONFIGURE clears them. */
#define LR_LIMITS_LEN 17
/* bit2: an E-stop is wired (a normally-closed switch from the E-stop pin to GND: the
 * pin high, pressed or its wire broken, stops the run and latches until a ZERO finds it
 * released) */
enum { LR_TRIP_SPEED = 1, LR_TRIP_POSITION = 2, LR_TRIP_ESTOP = 4 };
/* CONFIGURE body without the levels */
#define LR_CONFIGURE_FIXED 29

uint16_t lr_crc16(const uint8_t *data, size_t len);
uint16_t lr_crc16_update(uint16_t crc, uint8_t byte);
/* returns encoded length (no delimiter); out must hold len + len/254 + 1 bytes */
size_t lr_cobs_encode(const uint8_t *in, size_t len, uint8_t *out);
/* returns decoded length, or -1 on malformed input (a zero byte, a code past the end) */
int lr_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap);
/* builds a whole wire frame (COBS + trailing 0x00); returns its length or 0 if too long */
size_t lr_frame_build(uint8_t type, uint8_t seq, const uint8_t *body, size_t body_len,
                      uint8_t *wire);

/* Streaming decoder: feed bytes; a complete, CRC-valid frame is reported once. It
 * resynchronises on the next 0x00 after garbage. */
typedef struct {
    uint8_t buf[LR_MAX_RAW];  /* decoded bytes of the frame being received */
    uint16_t len;             /* decoded length so far */
    uint8_t code;             /* COBS: bytes left in the current block */
    uint8_t add_zero;         /* COBS: emit a zero before the next block */
    uint8_t discard;          /* frame overflowed or malformed: skip to 0x00 */
    uint32_t frames_ok, crc_errors, framing_errors;
} lr_decoder_t;

typedef struct {
    uint8_t type, seq;
    const uint8_t *body;      /* points into the decoder's buffer */
    uint16_t body_len;
} lr_frame_t;

void lr_decoder_init(lr_decoder_t *d);
/* returns 1 when byte completes a valid frame (filled into *f), else 0 */
int lr_decoder_feed(lr_decoder_t *d, uint8_t byte, lr_frame_t *f);

static inline void lr_put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static inline void lr_put32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static inline uint16_t lr_get16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static inline uint32_t lr_get32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

#ifdef __cplusplus
}
#endif
#endif

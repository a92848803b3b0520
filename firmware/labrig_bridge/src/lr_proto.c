/* CRC-16/CCITT-FALSE and COBS; see lr_proto.h. */
#include "lr_proto.h"

uint16_t lr_crc16_update(uint16_t crc, uint8_t byte)
{
    /* bitwise: 8 shifts per byte is ~100 cycles on AVR, cheaper in flash than a table */
    crc ^= (uint16_t)byte << 8;
    for (uint8_t i = 0; i < 8; i++)
        crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    return crc;
}

uint16_t lr_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < len; i++)
        crc = lr_crc16_update(crc, data[i]);
    return crc;
}

/* Streaming COBS writer: frames are encoded as they are built, without a copy of the
 * raw frame (RAM is scarce on the Uno). Canonical: a full 254-byte block opens the next
 * block only if more data follows. */
typedef struct { uint8_t *out; size_t o, code_at; uint8_t code, open; } cobs_w_t;

static void cw_init(cobs_w_t *w, uint8_t *out) { w->out = out; w->code_at = 0; w->o = 1; w->code = 1; w->open = 1; }

static void cw_put(cobs_w_t *w, uint8_t b)
{
    if (!w->open) { w->code_at = w->o++; w->code = 1; w->open = 1; }
    if (b == 0) {
        w->out[w->code_at] = w->code; w->code_at = w->o++; w->code = 1;
    } else {
        w->out[w->o++] = b;
        if (++w->code == 0xFF) { w->out[w->code_at] = 0xFF; w->open = 0; }
    }
}

static size_t cw_end(cobs_w_t *w) { if (w->open) w->out[w->code_at] = w->code; return w->o; }

size_t lr_cobs_encode(const uint8_t *in, size_t len, uint8_t *out)
{
    cobs_w_t w;
    cw_init(&w, out);
    for (size_t i = 0; i < len; i++) cw_put(&w, in[i]);
    return cw_end(&w);
}

int lr_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_cap)
{
    size_t i = 0, o = 0;
    while (i < len) {
        uint8_t code = in[i++];
        if (code == 0) return -1;
        for (uint8_t k = 1; k < code; k++) {
            if (i >= len || in[i] == 0 || o >= out_cap) return -1;
            out[o++] = in[i++];
        }
        if (code != 0xFF && i < len) {
            if (o >= out_cap) return -1;
            out[o++] = 0;
        }
    }
    return (int)o;
}

size_t lr_frame_build(uint8_t type, uint8_t seq, const uint8_t *body, size_t body_len,
                      uint8_t *wire)
{
    if (body_len > LR_MAX_BODY) return 0;
    cobs_w_t w;
    cw_init(&w, wire);
    uint16_t crc = lr_crc16_update(lr_crc16_update(0xFFFF, type), seq);
    cw_put(&w, type);
    cw_put(&w, seq);
    for (size_t i = 0; i < body_len; i++) {
        crc = lr_crc16_update(crc, body[i]);
        cw_put(&w, body[i]);
    }
    cw_put(&w, (uint8_t)(crc >> 8));  /* CRC big-endian: the CRC is defined MSB first */
    cw_put(&w, (uint8_t)crc);
    size_t n = cw_end(&w);
    wire[n++] = 0;
    return n;
}

void lr_decoder_init(lr_decoder_t *d)
{
    d->len = 0; d->code = 0; d->add_zero = 0; d->discard = 0;
    d->frames_ok = d->crc_errors = d->framing_errors = 0;
}

static void dec_reset(lr_decoder_t *d) { d->len = 0; d->code = 0; d->add_zero = 0; d->discard = 0; }

int lr_decoder_feed(lr_decoder_t *d, uint8_t byte, lr_frame_t *f)
{
    if (byte == 0) {
        int ok = 0;
        if (d->discard) {
            d->framing_errors++;
        } else if (d->code != 0) {
            d->framing_errors++;          /* delimiter inside a COBS block: truncated frame */
        } else if (d->len == 0) {
            /* empty frame (back-to-back delimiters): used to flush, not an error */
        } else if (d->len < 4) {
            d->framing_errors++;
        } else {
            uint16_t crc = lr_crc16(d->buf, (size_t)d->len - 2);
            uint16_t got = (uint16_t)((d->buf[d->len - 2] << 8) | d->buf[d->len - 1]);
            if (crc != got) {
                d->crc_errors++;
            } else {
                d->frames_ok++;
                f->type = d->buf[0]; f->seq = d->buf[1];
                f->body = d->buf + 2; f->body_len = (uint16_t)(d->len - 4);
                ok = 1;
            }
        }
        dec_reset(d);
        return ok;
    }
    if (d->discard) return 0;
    if (d->code == 0) {                   /* this byte is a COBS code */
        if (d->add_zero) {
            if (d->len >= LR_MAX_RAW) { d->discard = 1; return 0; }
            d->buf[d->len++] = 0;
        }
        d->code = (uint8_t)(byte - 1);
        d->add_zero = (byte != 0xFF);
        return 0;
    }
    if (d->len >= LR_MAX_RAW) { d->discard = 1; return 0; }
    d->buf[d->len++] = byte;
    d->code--;
    return 0;
}

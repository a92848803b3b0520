/* Residual error rate of the link framing: how often does a corrupted frame pass the
 * checks? Offline, seeded, with the firmware's own decoder (lr_proto.c, the same rules
 * as the host's StreamDecoder; both are checked against test_vectors.json).
 *
 *   make -C firmware residual                      (defaults below, ~2 min)
 *   build/host/crc_residual [-p 1e-2] [-n 100000000] [-s 1]
 *
 * A continuous stream of full SAMPLES frames (91 wire bytes, as at any rate above
 * 100 Hz) passes a channel that, per byte, drops it with probability p/2 or flips one
 * random bit with probability p/2 (the model of tests/linkproxy.py). Every frame the
 * decoder accepts is compared with the frames that were sent; a frame that differs from
 * all of them is a residual error. Three levels are counted:
 *   crc    passes COBS, the length limits and the CRC-16        (what the decoder delivers)
 *   body   ... and its body parses for its type (SAMPLES: 5 + 8n bytes, n >= 1; the host
 *          drops anything else as a bad frame)
 *   data   ... and is a SAMPLES frame whose first index lies where the host expects data
 *          (next index .. next + 80): it would be stored as a wrong sample
 * "corrupted" counts frames with at least one damaged byte (delimiter included). */
#define _POSIX_C_SOURCE 200809L   /* getopt with -std=c11 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "lr_proto.h"

static uint64_t rng_state;
static uint64_t rnd(void)   /* splitmix64: fast, seedable, good enough for fault positions */
{
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

#define RING 8
typedef struct { uint8_t raw[LR_MAX_RAW]; uint16_t len; uint32_t first; } sent_t;

static void poisson_ci(double k, double *lo, double *hi)
{   /* Wilson-Hilferty approximation of the exact 95 % Poisson interval */
    *lo = k > 0 ? k * pow(1 - 1 / (9 * k) - 1.96 / (3 * sqrt(k)), 3) : 0;
    double k1 = k + 1;
    *hi = k1 * pow(1 - 1 / (9 * k1) + 1.96 / (3 * sqrt(k1)), 3);
}

int main(int argc, char **argv)
{
    double p = 1e-2;
    long long n_frames = 100000000LL;
    uint64_t seed = 1;
    int c;
    while ((c = getopt(argc, argv, "p:n:s:")) != -1) {
        if (c == 'p') p = atof(optarg);
        else if (c == 'n') n_frames = atoll(optarg);
        else if (c == 's') seed = strtoull(optarg, NULL, 10);
        else { fprintf(stderr, "usage: %s [-p per-byte fault rate] [-n frames] [-s seed]\n", argv[0]); return 2; }
    }
    rng_state = seed;
    /* faults as integer thresholds on 64-bit draws: drop below t_drop, flip below t_fault */
    const uint64_t t_drop = (uint64_t)(p / 2 * 18446744073709551616.0);
    const uint64_t t_fault = (uint64_t)(p * 18446744073709551616.0);

    static sent_t ring[RING];
    lr_decoder_t dec;
    lr_decoder_init(&dec);
    lr_frame_t f;
    uint8_t body[5 + LR_BATCH * LR_SAMPLE_BYTES], wire[LR_MAX_WIRE];
    long long corrupted = 0, accepted_ok = 0, wrong_crc = 0, wrong_body = 0, wrong_data = 0;
    long long bytes = 0;
    uint32_t next_expected = 0;   /* the host's next index: after the last good frame */
    uint16_t dac = 2048;

    for (long long k = 0; k < n_frames; k++) {
        /* a realistic SAMPLES frame: index, square-wave DAC word, noisy 10-bit ADC words */
        uint32_t first = (uint32_t)(k * LR_BATCH);
        lr_put32(body, first);
        body[4] = LR_BATCH;
        if (k % 50 == 0) dac = dac == 2663 ? 1433 : 2663;
        for (int i = 0; i < LR_BATCH; i++) {
            uint64_t r = rnd();
            uint8_t *q = body + 5 + i * LR_SAMPLE_BYTES;
            lr_put16(q, dac);
            lr_put16(q + 2, (uint16_t)(512 + (r & 0xFF)));
            lr_put16(q + 4, (uint16_t)(300 + ((r >> 8) & 0x3F)));
            lr_put16(q + 6, (uint16_t)((r >> 16) & 0x3FF));
        }
        size_t n = lr_frame_build(LR_SAMPLES, (uint8_t)k, body, sizeof body, wire);
        sent_t *s = &ring[k % RING];
        s->raw[0] = LR_SAMPLES; s->raw[1] = (uint8_t)k;
        memcpy(s->raw + 2, body, sizeof body);
        s->len = (uint16_t)(2 + sizeof body);
        s->first = first;
        bytes += (long long)n;

        int hit = 0;
        for (size_t i = 0; i < n; i++) {
            uint8_t b = wire[i];
            uint64_t x = rnd();
            if (x < t_fault) {
                hit = 1;
                if (x < t_drop) continue;
                b ^= (uint8_t)(1u << (rnd() & 7));
            }
            if (!lr_decoder_feed(&dec, b, &f)) continue;
            /* accepted: is it one of the frames sent? */
            int same = 0;
            for (int j = 0; j < RING && !same; j++) {
                const sent_t *o = &ring[j];
                same = o->len == f.body_len + 2 && o->raw[0] == f.type && o->raw[1] == f.seq &&
                       !memcmp(o->raw + 2, f.body, f.body_len);
                if (same) next_expected = o->first + LR_BATCH;
            }
            if (same) { accepted_ok++; continue; }
            wrong_crc++;
            if (f.type == LR_SAMPLES && f.body_len >= 5 && f.body[4] >= 1 &&
                f.body_len == 5u + 8u * f.body[4]) {
                wrong_body++;
                uint32_t fi = lr_get32(f.body);
                if (fi >= next_expected && fi <= next_expected + 8 * LR_BATCH) wrong_data++;
            } else if ((f.type == LR_ACK && f.body_len == 2) || (f.type == LR_DONE && f.body_len == 8) ||
                       (f.type == LR_STATUS && f.body_len == 29) || (f.type == LR_HELLO && f.body_len >= 19) ||
                       (f.type == LR_ERROR && f.body_len >= 1)) {
                wrong_body++;
            }
        }
        corrupted += hit;
        if (p == 0 && accepted_ok != k + 1) { fprintf(stderr, "self-test failed at frame %lld\n", k); return 1; }
    }
    double lo, hi;
    printf("per-byte fault rate %g (half drops, half bit flips), seed %llu\n", p, (unsigned long long)seed);
    printf("frames sent %lld (%lld bytes), corrupted %lld (%.1f %%), delivered intact %lld\n",
           n_frames, bytes, corrupted, 100.0 * corrupted / n_frames, accepted_ok);
    printf("decoder: %u CRC errors, %u framing errors\n", dec.crc_errors, dec.framing_errors);
    const char *names[3] = {"crc", "body", "data"};
    long long counts[3] = {wrong_crc, wrong_body, wrong_data};
    for (int i = 0; i < 3; i++) {
        poisson_ci((double)counts[i], &lo, &hi);
        if (counts[i])
            printf("wrong frames passing %-4s: %lld = 1 in %.3g corrupted frames (95 %% CI 1 in %.3g .. %.3g)\n",
                   names[i], counts[i], (double)corrupted / counts[i], corrupted / hi,
                   lo > 0 ? corrupted / lo : INFINITY);
        else
            printf("wrong frames passing %-4s: 0 (95 %% CI: fewer than 1 in %.3g corrupted frames)\n",
                   names[i], corrupted / hi);
    }
    return 0;
}

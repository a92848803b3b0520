/* Host unit tests of the portable core: protocol against firmware/test_vectors.json,
 * then the bridge state machine through a fake HAL. Prints "N passed, N failed". */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "lr_proto.h"
#include "lr_core.h"
#include "lr_hal.h"
#include "jsonmini.h"
#include "lr_hbridge.h"

static int passed, failed;
#define CHECK(cond, ...) do { if (cond) passed++; else { failed++; \
    printf("FAIL %s:%d: ", __FILE__, __LINE__); printf(__VA_ARGS__); printf("\n"); } } while (0)

static size_t unhex(const char *h, uint8_t *out, size_t cap)
{
    size_t n = strlen(h) / 2;
    if (n > cap) { fprintf(stderr, "hex too long\n"); exit(2); }
    for (size_t i = 0; i < n; i++) { unsigned v; sscanf(h + 2 * i, "%2x", &v); out[i] = (uint8_t)v; }
    return n;
}

/* ---------------- fake HAL ---------------- */
static uint8_t txbuf[1 << 20];
static size_t txlen;
static uint8_t rxq[1 << 16];
static size_t rxhead, rxtail;
static uint32_t now_ms;
static int timer_on, adc_pending, adc_auto = 1;
static uint16_t dac_hw, dac_min_seen = 0xFFFF, dac_max_seen;
static uint16_t adc_vals[3] = {100, 200, 300};

void hal_dac_write(uint16_t w)
{
    dac_hw = w;
    if (w < dac_min_seen) dac_min_seen = w;
    if (w > dac_max_seen) dac_max_seen = w;
}
void hal_adc_start(void)
{
    if (adc_auto) lr_core_sample_done(adc_vals[0], adc_vals[1], adc_vals[2]);
    else adc_pending = 1;
}
int32_t hal_position(void) { return 0; }
int hal_rx_read(void) { return rxtail < rxhead ? rxq[rxtail++] : -1; }
uint16_t hal_tx_free(void) { return 1000; }
void hal_tx_write(const uint8_t *d, uint16_t n)
{
    if (txlen + n > sizeof txbuf) txlen = 0;
    memcpy(txbuf + txlen, d, n); txlen += n;
}
uint32_t hal_millis(void) { return now_ms; }
void hal_timer_start(uint16_t r) { (void)r; timer_on = 1; }
void hal_timer_stop(void) { timer_on = 0; }
uint8_t hal_lock(void) { return 0; }
void hal_unlock(uint8_t s) { (void)s; }
/* the index latch as the H-bridge layer keeps it, fed by the tests */
static lr_quad_t t_quad;
static lr_index_t t_idx;
static uint16_t t_faults;
uint8_t hal_index_take(int32_t *count, uint32_t *sample, uint16_t *pulses)
{
    if (!t_idx.fresh) return 0;
    *count = t_idx.count; *sample = t_idx.sample; *pulses = t_idx.pulses;
    t_idx.fresh = 0;
    return 1;
}
void hal_index_reset(void) { lr_index_reset(&t_idx, 0); }
uint16_t hal_encoder_faults(void) { return t_faults; }
static uint8_t t_estop;
uint8_t hal_estop(void) { return t_estop; }
static uint32_t t_id, t_id_writes;   /* the EEPROM's id */
uint32_t hal_id_read(void) { return t_id; }
void hal_id_write(uint32_t id) { t_id = id; t_id_writes++; }

static void host_send(uint8_t type, uint8_t seq, const uint8_t *body, size_t len)
{
    uint8_t wire[LR_MAX_WIRE];
    size_t n = lr_frame_build(type, seq, body, len, wire);
    memcpy(rxq + rxhead, wire, n); rxhead += n;
}

/* decode everything the board sent since the last call */
typedef struct { uint8_t type, seq; uint8_t body[LR_MAX_BODY]; uint16_t len; } msg_t;
static msg_t msgs[4096];
static int nmsgs;
static lr_decoder_t hostdec;
static size_t txdone;
static void collect(void)
{
    lr_frame_t f;
    for (; txdone < txlen; txdone++)
        if (lr_decoder_feed(&hostdec, txbuf[txdone], &f) && nmsgs < 4096) {
            msgs[nmsgs].type = f.type; msgs[nmsgs].seq = f.seq; msgs[nmsgs].len = f.body_len;
            memcpy(msgs[nmsgs].body, f.body, f.body_len); nmsgs++;
        }
}
static int find(uint8_t type) { for (int i = 0; i < nmsgs; i++) if (msgs[i].type == type) return i; return -1; }

static void reset_all(void)
{
    txlen = txdone = 0; rxhead = rxtail = 0; nmsgs = 0; now_ms = 0; timer_on = 0;
    adc_auto = 1; adc_pending = 0; dac_min_seen = 0xFFFF; dac_max_seen = 0;
    lr_decoder_init(&hostdec);
    lr_core_init(1, "labrig-fw test", 4000);
}

static size_t cfg_body(uint8_t *b, uint8_t loop, uint8_t wave, uint16_t rate, uint32_t n,
                       uint32_t lead, uint32_t seg, uint16_t lo, uint16_t hi, uint16_t wd,
                       const uint16_t *lv, uint8_t nl)
{
    b[0] = loop; b[1] = wave; lr_put16(b + 2, rate); lr_put32(b + 4, n); lr_put32(b + 8, lead);
    lr_put32(b + 12, seg); lr_put16(b + 16, 2048); lr_put16(b + 18, lo); lr_put16(b + 20, hi);
    lr_put16(b + 22, wd); lr_put16(b + 24, 1000); lr_put16(b + 26, 100); b[28] = nl;
    for (int i = 0; i < nl; i++) lr_put16(b + 29 + 2 * i, lv[i]);
    return 29 + 2u * nl;
}

/* how the run tests begin: reset, CONFIGURE (seq 1) with the body cfg_body builds in b
 * from the same arguments, START (seq 2), one poll; returns the body's length for a test
 * that sends the same CONFIGURE again */
static size_t configure_and_start(uint8_t *b, uint8_t loop, uint8_t wave, uint16_t rate, uint32_t n,
                                  uint32_t lead, uint32_t seg, uint16_t lo, uint16_t hi, uint16_t wd,
                                  const uint16_t *lv, uint8_t nl)
{
    reset_all();
    size_t len = cfg_body(b, loop, wave, rate, n, lead, seg, lo, hi, wd, lv, nl);
    host_send(LR_CONFIGURE, 1, b, len);
    host_send(LR_START, 2, NULL, 0);
    lr_core_poll();
    return len;
}

/* run the timer for n ticks with the main loop polled after each, heartbeat every 100 ms */
static void run_ticks(int n, int heartbeat)
{
    for (int i = 0; i < n; i++) {
        if (timer_on) lr_core_tick();
        if (i % 1 == 0) now_ms++;
        if (heartbeat && now_ms % 100 == 0) host_send(LR_HEARTBEAT, 0, NULL, 0);
        lr_core_poll();
    }
}

/* how many DAC words of the SAMPLES collected differ from want(k, ctx), k the sample's
 * index in the run; *seen: how many words there were */
static uint32_t bad_words(uint16_t (*want)(uint32_t k, const void *ctx), const void *ctx,
                          uint32_t *seen)
{
    uint32_t bad = 0;
    *seen = 0;
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type != LR_SAMPLES) continue;
        uint32_t first = lr_get32(msgs[i].body);
        for (int j = 0; j < msgs[i].body[4]; j++) {
            if (lr_get16(msgs[i].body + 5 + 8 * j) != want(first + j, ctx)) bad++;
            (*seen)++;
        }
    }
    return bad;
}

/* ---------------- vector tests ---------------- */
typedef struct { uint32_t lead; uint16_t zero; size_t nw; const uint8_t *raw; } pwl_t;
/* the word the host's rule plays at sample k: 0 V in the lead-in, then the vector's words
 * (0xFFFF, never played, past them) */
static uint16_t pwl_word(uint32_t k, const void *ctx)
{
    const pwl_t *p = ctx;
    return k < p->lead ? p->zero : (k - p->lead < p->nw ? lr_get16(p->raw + 2 * (k - p->lead)) : 0xFFFF);
}

/* The board plays a pwl word for word as the host's rule says (the vector's words come
 * from labrig.bridge.protocol.pwl_words): linear between breakpoints in integers,
 * the last breakpoint held, 0 V in the lead-in. */
static void test_pwl(jnode_t *v)
{
    static uint8_t body[256];
    reset_all();
    size_t n = unhex(json_get(v, "configure_body")->str, body, sizeof body);
    uint32_t lead = (uint32_t)json_get(v, "lead_in")->num, total = (uint32_t)json_get(v, "n_samples")->num;
    uint16_t zero = (uint16_t)json_get(v, "dac_zero")->num;
    static uint8_t raw[8192];
    size_t nw = unhex(json_get(v, "words")->str, raw, sizeof raw) / 2;
    host_send(LR_CONFIGURE, 1, body, n);
    host_send(LR_START, 2, NULL, 0);
    lr_core_poll();
    run_ticks(total + 200, 1);
    collect();
    pwl_t pwl = {lead, zero, nw, raw};
    uint32_t seen, bad = bad_words(pwl_word, &pwl, &seen);
    CHECK(seen == total && bad == 0, "pwl played as the host's rule says (seen %u of %u, bad %u)",
          seen, total, bad);
}

/* The MS150 board's own loop outputs, sample by sample, the word labrig's model computes
 * for the same pot and tacho words (the vector's, from the model's law) */
static void test_board_loop_vector(jnode_t *v)
{
    static uint8_t body[256];
    reset_all();
    size_t n = unhex(json_get(v, "configure_body")->str, body, sizeof body);
    int total = (int)json_get(v, "n_samples")->num, bad = 0, k = 0;
    host_send(LR_CONFIGURE, 1, body, n);
    host_send(LR_START, 2, NULL, 0);
    for (int i = 0; i < 3; i++) lr_core_poll();
    jnode_t *p = json_get(v, "pot")->child, *t = json_get(v, "tacho")->child, *w = json_get(v, "words")->child;
    for (; k < total && p && t && w; k++, p = p->next, t = t->next, w = w->next) {
        adc_vals[0] = (uint16_t)t->num; adc_vals[1] = (uint16_t)p->num;
        lr_core_tick();
        if (dac_hw != (uint16_t)w->num) bad++;
    }
    CHECK(k == total && bad == 0 && lr_core_state() == LR_STATE_RUNNING,
          "the board's loop outputs the model's words (%d of %d differ)", bad, k);
    adc_vals[0] = 100; adc_vals[1] = 200;
}

static void test_vectors(const char *path)
{
    FILE *fp = fopen(path, "rb");
    CHECK(fp != NULL, "open %s", path);
    if (!fp) return;
    fseek(fp, 0, SEEK_END); long sz = ftell(fp); fseek(fp, 0, SEEK_SET);
    char *text = malloc((size_t)sz + 1);
    size_t got = fread(text, 1, (size_t)sz, fp); text[got] = 0; fclose(fp);
    jnode_t *root = json_parse(text);
    CHECK(root != NULL, "parse json");
    if (!root) { free(text); return; }
    static uint8_t a[4096], b[4096], c[4096];

    for (jnode_t *v = json_get(root, "crc16_ccitt_false")->child; v; v = v->next) {
        jnode_t *asc = json_get(v, "ascii"), *hx = json_get(v, "hex");
        size_t n = asc ? strlen(asc->str) : unhex(hx->str, a, sizeof a);
        if (asc) memcpy(a, asc->str, n);
        unsigned want; sscanf(json_get(v, "crc")->str, "%x", &want);
        CHECK(lr_crc16(a, n) == want, "crc of %s: %04x want %04x", asc ? asc->str : "hex", lr_crc16(a, n), want);
    }
    for (jnode_t *v = json_get(root, "cobs")->child; v; v = v->next) {
        size_t nd = unhex(json_get(v, "decoded")->str, a, sizeof a);
        size_t ne = unhex(json_get(v, "encoded")->str, b, sizeof b);
        size_t m = lr_cobs_encode(a, nd, c);
        CHECK(m == ne && !memcmp(c, b, ne), "cobs encode of %zu bytes", nd);
        int k = lr_cobs_decode(b, ne, c, sizeof c);
        CHECK(k == (int)nd && !memcmp(c, a, nd), "cobs decode of %zu bytes", nd);
    }
    for (jnode_t *v = json_get(root, "cobs_invalid")->child; v; v = v->next) {
        size_t n = unhex(v->str, a, sizeof a);
        CHECK(lr_cobs_decode(a, n, c, sizeof c) < 0, "invalid cobs %s rejected", v->str);
    }
    for (jnode_t *v = json_get(root, "frames")->child; v; v = v->next) {
        const char *name = json_get(v, "name")->str;
        uint8_t type = (uint8_t)json_get(v, "type")->num, seq = (uint8_t)json_get(v, "seq")->num;
        size_t nb = unhex(json_get(v, "body")->str, a, sizeof a);
        size_t nw = unhex(json_get(v, "wire")->str, b, sizeof b);
        size_t m = lr_frame_build(type, seq, a, nb, c);
        CHECK(m == nw && !memcmp(b, c, nw), "build frame %s", name);
        lr_decoder_t d; lr_frame_t f; int nf = 0;
        lr_decoder_init(&d);
        for (size_t i = 0; i < nw; i++)
            if (lr_decoder_feed(&d, b[i], &f)) {
                nf++;
                CHECK(f.type == type && f.seq == seq && f.body_len == nb && !memcmp(f.body, a, nb),
                      "decode frame %s", name);
            }
        CHECK(nf == 1, "frame %s decoded once", name);
    }
    for (jnode_t *v = json_get(root, "reject")->child; v; v = v->next) {
        const char *name = json_get(v, "name")->str, *kind = json_get(v, "error")->str;
        size_t nw = unhex(json_get(v, "wire")->str, b, sizeof b);
        lr_decoder_t d; lr_frame_t f; int nf = 0;
        lr_decoder_init(&d);
        for (size_t i = 0; i < nw; i++) nf += lr_decoder_feed(&d, b[i], &f);
        CHECK(nf == 0, "reject %s", name);
        if (!strcmp(kind, "crc")) CHECK(d.crc_errors == 1 && d.framing_errors == 0, "%s counted as crc", name);
        else if (!strcmp(kind, "framing")) CHECK(d.framing_errors == 1 && d.crc_errors == 0, "%s counted as framing", name);
        else CHECK(d.framing_errors + d.crc_errors == 1, "%s counted once", name);
    }
    {
        jnode_t *s = json_get(root, "stream");
        size_t nw = unhex(json_get(s, "wire")->str, b, sizeof b);
        lr_decoder_t d; lr_frame_t f;
        lr_decoder_init(&d);
        jnode_t *want = json_get(s, "frames")->child;
        int nf = 0;
        for (size_t i = 0; i < nw; i++)
            if (lr_decoder_feed(&d, b[i], &f)) {
                nf++;
                size_t nb = want ? unhex(json_get(want, "body")->str, a, sizeof a) : 0;
                CHECK(want && f.type == (uint8_t)json_get(want, "type")->num && f.body_len == nb &&
                      !memcmp(f.body, a, nb), "stream frame %d", nf);
                if (want) want = want->next;
            }
        CHECK(nf == (int)json_len(json_get(s, "frames")), "stream frame count %d", nf);
        CHECK(d.crc_errors == (uint32_t)json_get(s, "crc_errors")->num &&
              d.framing_errors == (uint32_t)json_get(s, "framing_errors")->num,
              "stream error counts %u %u", d.crc_errors, d.framing_errors);
    }
    test_pwl(json_get(root, "pwl"));
    test_board_loop_vector(json_get(root, "board_loop"));
    json_free(root);
    free(text);
}

/* ---------------- core tests ---------------- */
static int expect_square(uint32_t i, uint32_t lead, uint32_t half, uint16_t hi, uint16_t lo)
{
    if (i < lead) return 2048;
    return ((i - lead) / half) % 2 == 0 ? hi : lo;
}

static void test_hello_and_zero_at_reset(void)
{
    dac_hw = 4095;
    reset_all();
    CHECK(dac_hw == 2048, "0 V at reset (word %u)", dac_hw);
    host_send(LR_HELLO_REQ, 9, NULL, 0);
    lr_core_poll(); collect();
    int k = find(LR_HELLO);
    CHECK(k >= 0 && msgs[k].body[0] == LR_PROTOCOL_VERSION && lr_get16(msgs[k].body + 4) == 4000,
          "HELLO answers HELLO_REQ");
}

static void test_square_run(void)
{
    uint8_t b[128];
    uint16_t lv[2] = {2663, 1433};
    configure_and_start(b, 0, LR_WAVE_SQUARE, 1000, 4500, 500, 1000, 1024, 3072, 500, lv, 2);
    CHECK(timer_on, "timer started");
    run_ticks(6000, 1);
    collect();
    uint32_t next = 0, bad = 0;
    int done = 0, acks = 0;
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type == LR_ACK) acks++;
        if (msgs[i].type == LR_DONE) { done++; CHECK(lr_get32(msgs[i].body) == 4500 && lr_get32(msgs[i].body + 4) == 0, "DONE body"); }
        if (msgs[i].type != LR_SAMPLES) continue;
        uint32_t first = lr_get32(msgs[i].body);
        uint8_t cnt = msgs[i].body[4];
        if (first != next) bad++;
        for (int j = 0; j < cnt; j++) {
            uint16_t w = lr_get16(msgs[i].body + 5 + 8 * j);
            if (w != expect_square(first + j, 500, 1000, 2663, 1433)) bad++;
            if (lr_get16(msgs[i].body + 5 + 8 * j + 2) != 100) bad++;
        }
        next = first + cnt;
    }
    CHECK(acks == 2, "CONFIGURE and START acked (%d)", acks);
    CHECK(next == 4500 && bad == 0, "4500 samples in order with the planned square (next %u, bad %u)", next, bad);
    CHECK(done == 1, "one DONE (%d)", done);
    CHECK(dac_hw == 2048 && !timer_on, "0 V and timer off after the end");
    CHECK(lr_core_counters()->watchdog_trips == 0, "no watchdog trip with heartbeats");
}

/* the staircase of test_staircase: 0 V for the 250-sample lead-in, then each level of
 * lv for 300 samples, the last one held */
static uint16_t staircase_word(uint32_t k, const void *ctx)
{
    const uint16_t *lv = ctx;
    return k < 250 ? 2048 : lv[(k - 250) / 300 > 3 ? 3 : (k - 250) / 300];
}

static void test_staircase(void)
{
    uint8_t b[128];
    uint16_t lv[4] = {2048, 2458, 2867, 1638};
    configure_and_start(b, 1, LR_WAVE_STAIRCASE, 500, 2000, 250, 300, 1024, 3072, 500, lv, 4);
    run_ticks(2200, 1);
    collect();
    uint32_t total, bad = bad_words(staircase_word, lv, &total);
    CHECK(total == 2000 && bad == 0, "staircase holds the last level (total %u, bad %u)", total, bad);
}

/* a fresh board's answer to one CONFIGURE of body b: the ERROR code, -1 if none came */
static int configure_error(const uint8_t *b, size_t n)
{
    reset_all();
    host_send(LR_CONFIGURE, 1, b, n);
    lr_core_poll(); collect();
    int k = find(LR_ERROR);
    return k >= 0 ? msgs[k].body[0] : -1;
}

static void test_limits(void)
{
    uint8_t b[128];
    uint16_t lv[2] = {3500, 1433};  /* 3500 is beyond dac_max */
    size_t n = configure_and_start(b, 0, LR_WAVE_SQUARE, 1000, 100, 0, 10, 1024, 3072, 500, lv, 2);
    collect();
    int k = find(LR_ERROR);
    CHECK(k >= 0 && msgs[k].body[0] == LR_ERR_LIMIT, "level beyond the limit refused");
    CHECK(k >= 0 && k + 1 < nmsgs && msgs[k + 1].type == LR_ERROR && msgs[k + 1].body[0] == LR_ERR_NOT_CONFIGURED,
          "START after a refused CONFIGURE refused");
    CHECK(!timer_on && dac_hw == 2048, "output stays at 0 V");

    uint16_t lv2[2] = {2100, 2000};
    n = cfg_body(b, 0, LR_WAVE_SQUARE, 1000, 100, 0, 10, 0, 4095, 500, lv2, 2);  /* limits beyond firmware's */
    CHECK(configure_error(b, n) == LR_ERR_LIMIT, "limits wider than the firmware's refused");
    n = cfg_body(b, 0, LR_WAVE_SQUARE, 9000, 100, 0, 10, 1024, 3072, 500, lv2, 2);
    CHECK(configure_error(b, n) == LR_ERR_RATE, "rate above max refused");
}

static void test_watchdog(void)
{
    uint8_t b[128];
    uint16_t lv[1] = {2600};
    configure_and_start(b, 0, LR_WAVE_CONSTANT, 1000, 100000, 0, 0, 1024, 3072, 300, lv, 1);
    run_ticks(250, 0);
    CHECK(dac_hw == 2600 && timer_on, "running before the watchdog time");
    run_ticks(100, 0);
    collect();
    int k = find(LR_ERROR);
    CHECK(k >= 0 && msgs[k].body[0] == LR_ERR_WATCHDOG, "watchdog error sent");
    CHECK(dac_hw == 2048 && !timer_on, "silent host: output 0 V (word %u)", dac_hw);
    CHECK(lr_core_counters()->watchdog_trips == 1, "watchdog trip counted");
}

static void test_overrun_gap(void)
{
    uint8_t b[128];
    uint16_t lv[1] = {2300};
    configure_and_start(b, 0, LR_WAVE_CONSTANT, 1000, 100, 0, 0, 1024, 3072, 500, lv, 1);
    adc_auto = 0;
    for (int i = 0; i < 120; i++) {
        if (timer_on) lr_core_tick();
        /* conversions of sample 40 overrun into the next period */
        if (adc_pending && i != 40) { adc_pending = 0; lr_core_sample_done(1, 2, 3); }
        now_ms++;
        lr_core_poll();
    }
    collect();
    uint32_t got = 0, next = 0, gaps = 0;
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type != LR_SAMPLES) continue;
        uint32_t first = lr_get32(msgs[i].body);
        if (first != next) gaps += first - next;
        got += msgs[i].body[4];
        next = first + msgs[i].body[4];
    }
    CHECK(got == 99 && gaps == 1, "overrun gives exactly one gap (got %u, gaps %u)", got, gaps);
    int k = find(LR_DONE);
    CHECK(k >= 0 && lr_get32(msgs[k].body + 4) == 1, "DONE reports the lost sample");
}

static void test_stop_and_garbage(void)
{
    reset_all();
    uint8_t b[128];
    uint16_t lv[1] = {2500};
    size_t n = cfg_body(b, 0, LR_WAVE_STEP, 1000, 100000, 10, 0, 1024, 3072, 500, lv, 1);
    /* trailing garbage without a delimiter would swallow the next frame: the host
     * prefixes commands with a 0x00, as here */
    const uint8_t junk[] = {0x13, 0x37, 0xFF, 0x00, 0x05, 0x01, 0x00};
    memcpy(rxq + rxhead, junk, sizeof junk); rxhead += sizeof junk;
    host_send(LR_CONFIGURE, 1, b, n);
    host_send(LR_START, 2, NULL, 0);
    lr_core_poll();
    run_ticks(100, 1);
    CHECK(dac_hw == 2500, "step applied after the lead-in");
    host_send(LR_STOP, 3, NULL, 0);
    lr_core_poll();
    CHECK(dac_hw == 2048 && !timer_on, "STOP returns the output to 0 V");
    CHECK(lr_core_decoder()->framing_errors >= 1, "garbage counted, commands still understood");
}

/* a START retransmitted with the same seq (its ACK was lost) is acked again but never
 * restarts the run, neither while running nor after DONE; a new seq or a new CONFIGURE does */
static int count_samples(uint32_t *first_min)
{
    int total = 0;
    *first_min = 0xFFFFFFFFu;
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type != LR_SAMPLES) continue;
        uint32_t first = lr_get32(msgs[i].body);
        if (first < *first_min) *first_min = first;
        total += msgs[i].body[4];
    }
    return total;
}

static void test_start_retransmission(void)
{
    uint8_t b[128];
    uint16_t lv[2] = {2663, 1433};
    size_t n = configure_and_start(b, 0, LR_WAVE_SQUARE, 1000, 300, 20, 50, 1024, 3072, 500, lv, 2);
    run_ticks(100, 1);
    host_send(LR_START, 2, NULL, 0);          /* retransmission while running */
    run_ticks(400, 1);
    collect();
    uint32_t first_min;
    int acks = 0, busy = 0, done = 0, total = count_samples(&first_min);
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type == LR_ACK && msgs[i].body[0] == LR_START && msgs[i].body[1] == 2) acks++;
        if (msgs[i].type == LR_ERROR && msgs[i].body[0] == LR_ERR_BUSY) busy++;
        if (msgs[i].type == LR_DONE) done++;
    }
    CHECK(acks == 2 && busy == 0, "a repeated START is acked again (acks %d, busy %d)", acks, busy);
    CHECK(total == 300 && done == 1, "and does not restart the run (%d samples, %d DONE)", total, done);

    nmsgs = 0;
    host_send(LR_START, 2, NULL, 0);          /* retransmission after DONE */
    run_ticks(400, 1);
    collect();
    total = count_samples(&first_min);
    CHECK(total == 0 && !timer_on && dac_hw == 2048 && find(LR_ACK) >= 0,
          "a repeated START after DONE is acked, nothing restarts (%d samples)", total);

    nmsgs = 0;
    host_send(LR_START, 3, NULL, 0);          /* a new START (new seq) runs again */
    run_ticks(400, 1);
    collect();
    total = count_samples(&first_min);
    CHECK(total == 300 && first_min == 0, "a new START runs the experiment again (%d samples)", total);

    nmsgs = 0;
    host_send(LR_CONFIGURE, 4, b, n);         /* CONFIGURE forgets the START seq */
    host_send(LR_START, 3, NULL, 0);
    run_ticks(400, 1);
    collect();
    total = count_samples(&first_min);
    CHECK(total == 300, "after a CONFIGURE the same seq starts a new run (%d samples)", total);
}

static void test_fuzz(void)
{
    reset_all();
    srand(1);
    uint8_t b[128];
    for (int round = 0; round < 3000; round++) {
        int r = rand() % 4;
        if (r == 0) {  /* random bytes */
            for (int i = 0; i < 40; i++) rxq[rxhead++] = (uint8_t)rand();
        } else if (r == 1) {  /* a random but valid-CRC frame of random type */
            size_t len = (size_t)(rand() % 60);
            for (size_t i = 0; i < len; i++) b[i] = (uint8_t)rand();
            host_send((uint8_t)(rand() % 10), 0, b, len);
        } else if (r == 2) {  /* a plausible CONFIGURE with random levels, then START */
            uint16_t lv[3] = {(uint16_t)(rand() % 4096), (uint16_t)(rand() % 4096), (uint16_t)(rand() % 4096)};
            size_t n = cfg_body(b, (uint8_t)(rand() % 3), (uint8_t)(rand() % 5), (uint16_t)(rand() % 6000),
                                (uint32_t)(rand() % 500), (uint32_t)(rand() % 50), (uint32_t)(rand() % 30),
                                (uint16_t)(rand() % 4096), (uint16_t)(rand() % 4096), (uint16_t)(rand() % 1000),
                                lv, (uint8_t)(1 + rand() % 3));
            host_send(LR_CONFIGURE, 0, b, n);
            host_send(LR_START, 0, NULL, 0);
        }
        run_ticks(20, rand() % 2);
        if (rxhead > sizeof rxq - 4096) { rxhead = rxtail = 0; }
        if (txlen > sizeof txbuf / 2) { txlen = txdone = 0; }
    }
    CHECK(dac_min_seen >= 2048 - LR_FW_LIMIT_COUNTS && dac_max_seen <= 2048 + LR_FW_LIMIT_COUNTS,
          "fuzzed commands never drive the DAC past the firmware limit (%u..%u)", dac_min_seen, dac_max_seen);
}


/* ---------------- H-bridge rig: quadrature decoder and drive mapping ---------------- */
static void test_quadrature(void)
{
    /* forward walks ab 0 -> 2 -> 3 -> 1 -> 0 (A leads B) */
    static const uint8_t fwd[4] = {0, 2, 3, 1};
    /* every one of the 16 transitions, at each decoding */
    for (uint8_t dec = 1; dec <= 4; dec = (uint8_t)(dec * 2)) {
        for (uint8_t from = 0; from < 4; from++) {
            for (uint8_t to = 0; to < 4; to++) {
                lr_quad_t q;
                lr_quad_init(&q, dec, from & 2, from & 1);
                lr_quad_feed(&q, to & 2, to & 1);
                int pos_from = 0, pos_to = 0;
                for (int k = 0; k < 4; k++) { if (fwd[k] == from) pos_from = k; if (fwd[k] == to) pos_to = k; }
                int step = (pos_to - pos_from + 4) % 4;   /* 1 forward, 3 back, 2 illegal */
                int want = step == 1 ? 1 : step == 3 ? -1 : 0;
                int a_edge = ((from ^ to) & 2) != 0;
                int x1_edge = (from | to) == 2 && from != to;
                if (dec == 2 && !a_edge) want = 0;
                if (dec == 1 && !x1_edge) want = 0;
                CHECK(q.count == want, "x%u %u->%u: count %ld, want %d", dec, from, to, (long)q.count, want);
                CHECK(q.illegal == (uint32_t)(step == 2), "x%u %u->%u: illegal %lu", dec, from, to,
                      (unsigned long)q.illegal);
                CHECK(q.state == to, "x%u %u->%u: state %u", dec, from, to, q.state);
            }
        }
    }
    /* whole cycles: 4, 2 and 1 counts per cycle, back again to 0; dithering on every edge
     * never drifts */
    for (uint8_t dec = 1; dec <= 4; dec = (uint8_t)(dec * 2)) {
        lr_quad_t q;
        lr_quad_init(&q, dec, 0, 0);
        for (int k = 1; k <= 400; k++) lr_quad_feed(&q, fwd[k % 4] & 2, fwd[k % 4] & 1);
        CHECK(q.count == 100 * dec, "x%u: 100 cycles forward gave %ld", dec, (long)q.count);
        for (int k = 399; k >= 0; k--) lr_quad_feed(&q, fwd[k % 4] & 2, fwd[k % 4] & 1);
        CHECK(q.count == 0, "x%u: and back gave %ld", dec, (long)q.count);
        for (int k = 0; k < 4; k++) {   /* dither on each edge, then step over it */
            int32_t before = q.count;
            for (int r = 0; r < 50; r++) {
                lr_quad_feed(&q, fwd[(k + 1) % 4] & 2, fwd[(k + 1) % 4] & 1);
                lr_quad_feed(&q, fwd[k] & 2, fwd[k] & 1);
            }
            CHECK(q.count == before, "x%u: dithering on edge %d drifted by %ld", dec, k,
                  (long)(q.count - before));
            lr_quad_feed(&q, fwd[(k + 1) % 4] & 2, fwd[(k + 1) % 4] & 1);
        }
        CHECK(q.count == dec && q.illegal == 0, "x%u: one cycle after dithering gave %ld", dec,
              (long)q.count);
    }
    /* a count past 2^16 and below zero keeps its 32 bits */
    lr_quad_t q;
    lr_quad_init(&q, 4, 0, 0);
    for (long k = 1; k <= 200000; k++) lr_quad_feed(&q, fwd[(4 - k % 4) % 4] & 2, fwd[(4 - k % 4) % 4] & 1);
    CHECK(q.count == -200000, "200000 counts back gave %ld", (long)q.count);
}

/* The index latches the count of the state it marks (A = B = high at one place a turn),
 * the same turning either way and whichever interrupt runs first: the index's own (the
 * decoder fed the new A/B there) or the channels' (the index's then sees no change). */
static void test_index_latch(void)
{
    static const uint8_t fwd[4] = {0, 2, 3, 1};   /* ab forward; state 3 (A = B = 1) at k % 4 == 2 */
    const int per_turn = 40;                      /* edges a turn; the index at edge 42 + 40 m */
    for (int order = 0; order < 2; order++)
        for (int dir = -1; dir <= 1; dir += 2) {
            lr_quad_t q;
            lr_index_t x;
            lr_quad_init(&q, 4, 0, 0);
            lr_index_reset(&x, 0);
            int ok = 1, n = 0;
            for (int step = 1; step <= 400; step++) {
                int k = dir > 0 ? step : -step;    /* the shaft's edge index */
                uint8_t ab = fwd[((k % 4) + 4) % 4];
                uint8_t idx = ((k - 42) % per_turn + per_turn) % per_turn == 0;
                if (order == 0) lr_quad_feed(&q, ab & 2, ab & 1);   /* channels first */
                lr_index_feed(&x, &q, ab & 2, ab & 1, idx, (uint32_t)step);
                if (x.fresh) {
                    x.fresh = 0;
                    n++;
                    /* the count there is the edge index itself (x4 from 0 at rest) */
                    if (x.count != k) ok = 0;
                    if (x.sample != (uint32_t)step) ok = 0;
                }
            }
            CHECK(ok && n == 10 && x.pulses == 10 && q.illegal == 0,
                  "index order %d dir %d: %d pulses, latched count %ld (last edge)", order, dir, n,
                  (long)x.count);
        }
    /* a falling edge and a level held high latch nothing more */
    lr_quad_t q;
    lr_index_t x;
    lr_quad_init(&q, 4, 0, 0);
    lr_index_reset(&x, 0);
    lr_index_feed(&x, &q, 0, 0, 1, 5);
    lr_index_feed(&x, &q, 0, 0, 1, 6);
    lr_index_feed(&x, &q, 0, 0, 0, 7);
    CHECK(x.pulses == 1 && x.sample == 5, "one pulse per rising edge (%u)", x.pulses);
    /* a bench without an index wired: the pull-up holds it high from reset, nothing latches */
    lr_index_reset(&x, 1);
    lr_index_feed(&x, &q, 0, 0, 1, 1);
    CHECK(x.pulses == 0 && !x.fresh, "a pin high from reset is no pulse");
}

/* The board reports each index pulse of a run (INDEX: the sample it came before, the
 * latched count, the pulse number), none before START; STATUS carries the decoder's faults */
static void test_index_frames(void)
{
    uint8_t b[128];
    uint16_t lv[1] = {2600};
    lr_quad_init(&t_quad, 4, 0, 0);
    lr_index_reset(&t_idx, 0);
    lr_index_feed(&t_idx, &t_quad, 0, 0, 1, 0);   /* a pulse before the run: not its own */
    lr_index_feed(&t_idx, &t_quad, 0, 0, 0, 0);
    configure_and_start(b, 0, LR_WAVE_CONSTANT, 1000, 300, 0, 0, 1024, 3072, 500, lv, 1);
    int32_t counts[3] = {-7, 125, 100000};
    for (int i = 0; i < 3; i++) {
        run_ticks(50, 1);
        t_quad.count = counts[i];
        lr_index_feed(&t_idx, &t_quad, 0, 0, 1, lr_core_sample_index());
        lr_index_feed(&t_idx, &t_quad, 0, 0, 0, lr_core_sample_index());
        if (i == 1) {   /* two pulses between two polls: the latest is reported, numbered */
            t_quad.count = 130;
            lr_index_feed(&t_idx, &t_quad, 0, 0, 1, lr_core_sample_index());
            lr_index_feed(&t_idx, &t_quad, 0, 0, 0, lr_core_sample_index());
            counts[1] = 130;
        }
    }
    t_faults = 3;
    run_ticks(300, 1);
    host_send(LR_STATUS_REQ, 7, NULL, 0);
    lr_core_poll();
    collect();
    int n = 0, ok = 1;
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type != LR_INDEX) continue;
        ok &= msgs[i].len == 10 && n < 3;
        if (!ok) break;
        ok &= (int32_t)lr_get32(msgs[i].body + 4) == counts[n];
        ok &= lr_get32(msgs[i].body) == 50u * (n + 1);
        ok &= lr_get16(msgs[i].body + 8) == (n < 1 ? 1 : n + 2);
        n++;
    }
    CHECK(ok && n == 3, "three INDEX frames with their samples, counts and numbers (%d)", n);
    int k = find(LR_STATUS);
    CHECK(k >= 0 && lr_get16(msgs[k].body + 27) == 3, "STATUS carries the encoder's faults");
    t_faults = 0;
}

static void test_drive_map(void)
{
    const uint16_t zero = 256, top = 255;   /* 8-bit PWM, 9-bit word */
    for (uint8_t mode = 0; mode < 2; mode++)
        for (uint8_t brake = 0; brake < 2; brake++)
            for (int d = -300; d <= 300; d++) {
                int w = zero + d;
                if (w < 0 || w > 511) continue;
                lr_drive_t o = lr_drive_map((uint16_t)w, zero, top, mode, brake);
                int n = d < 0 ? -d : d;
                if (n > top + 1) n = top + 1;
                /* duty = the share of the period the motor is driven, in counts of top + 1 */
                int driven_a = o.pin_a == LR_PIN_PWM ? o.compare + 1 : o.pin_a == LR_PIN_PWM_INV ?
                               top - o.compare : o.pin_a == LR_PIN_HIGH ? top + 1 : 0;
                int driven_b = o.pin_b == LR_PIN_PWM ? o.compare + 1 : o.pin_b == LR_PIN_PWM_INV ?
                               top - o.compare : o.pin_b == LR_PIN_HIGH ? top + 1 : 0;
                int duty, sign;
                if (mode == LR_DRIVE_PWM_DIR) {
                    duty = driven_a;
                    sign = o.pin_b == LR_PIN_HIGH ? -1 : 1;
                    CHECK(o.pin_b == LR_PIN_HIGH || o.pin_b == LR_PIN_LOW, "DIR pin PWM'd at d %d", d);
                } else {
                    /* IN1/IN2: driven forward while IN1 high and IN2 low */
                    int fwd = o.pin_a == LR_PIN_HIGH || o.pin_a == LR_PIN_PWM;
                    int a_hi = fwd ? driven_a : driven_b, b_hi = fwd ? driven_b : driven_a;
                    duty = a_hi - b_hi;   /* high-high (brake) and low-low (coast) drive nothing */
                    sign = fwd ? 1 : -1;
                    if (n == 0) { duty = 0; sign = 1; }
                    CHECK(brake ? (o.pin_a != LR_PIN_PWM && o.pin_b != LR_PIN_PWM)
                                : (o.pin_a != LR_PIN_PWM_INV && o.pin_b != LR_PIN_PWM_INV &&
                                   o.pin_a != LR_PIN_HIGH && o.pin_b != LR_PIN_HIGH),
                          "mode %u brake %u d %d: off phase pins %u %u", mode, brake, d, o.pin_a, o.pin_b);
                }
                CHECK(duty == n && (n == 0 || sign == (d < 0 ? -1 : 1)),
                      "mode %u brake %u d %d: duty %d sign %d, want %d", mode, brake, d, duty, sign, n);
            }
    /* zero: coast (both low) or brake (both high); never a PWM at 0 V */
    lr_drive_t o = lr_drive_map(zero, zero, top, LR_DRIVE_IN1_IN2, 1);
    CHECK(o.pin_a == LR_PIN_HIGH && o.pin_b == LR_PIN_HIGH, "brake at zero");
    o = lr_drive_map(zero, zero, top, LR_DRIVE_IN1_IN2, 0);
    CHECK(o.pin_a == LR_PIN_LOW && o.pin_b == LR_PIN_LOW, "coast at zero");
    o = lr_drive_map(zero, zero, top, LR_DRIVE_PWM_DIR, 0);
    CHECK(o.pin_a == LR_PIN_LOW, "PWM pin low at zero");
}


static size_t limits_body(uint8_t *b, uint8_t flags, int32_t s_lo, int32_t s_hi, int32_t p_lo,
                          int32_t p_hi)
{
    b[0] = flags;
    lr_put32(b + 1, (uint32_t)s_lo); lr_put32(b + 5, (uint32_t)s_hi);
    lr_put32(b + 9, (uint32_t)p_lo); lr_put32(b + 13, (uint32_t)p_hi);
    return LR_LIMITS_LEN;
}

/* the last sample index the board sent, -1 if none */
static int64_t last_sample(void)
{
    int64_t last = -1;
    for (int i = 0; i < nmsgs; i++)
        if (msgs[i].type == LR_SAMPLES)
            last = (int64_t)lr_get32(msgs[i].body) + msgs[i].body[4] - 1;
    return last;
}

static void test_trips(void)
{
    uint8_t b[128], lb[LR_LIMITS_LEN];
    uint16_t lv[1] = {2600};
    const uint8_t whys[2] = {LR_TRIP_SPEED, LR_TRIP_POSITION};
    for (int w = 0; w < 2; w++) {
        reset_all();
        adc_vals[0] = 100; adc_vals[1] = 200;
        size_t n = cfg_body(b, 1, LR_WAVE_CONSTANT, 1000, 100000, 0, 0, 1024, 3072, 500, lv, 1);
        host_send(LR_CONFIGURE, 1, b, n);
        host_send(LR_LIMITS, 2, lb, limits_body(lb, LR_TRIP_SPEED | LR_TRIP_POSITION, 50, 150, 150, 250));
        host_send(LR_START, 3, NULL, 0);
        lr_core_poll();
        run_ticks(100, 1);
        CHECK(dac_hw == 2600 && timer_on, "running inside the limits");
        if (whys[w] == LR_TRIP_SPEED) adc_vals[0] = 151; else adc_vals[1] = 149;
        uint32_t at = lr_core_sample_index();
        lr_core_tick();   /* the sample past the limit */
        CHECK(dac_hw == 2048 && !timer_on, "trip %u: 0 V at the sample past the limit (word %u)",
              whys[w], dac_hw);
        run_ticks(50, 1);
        collect();
        int k = find(LR_ERROR);
        CHECK(k >= 0 && msgs[k].body[0] == LR_ERR_TRIP, "trip %u: TRIP reported", whys[w]);
        CHECK(last_sample() == (int64_t)at && find(LR_DONE) < 0,
              "trip %u: the run ends at the sample that tripped (last %lld), no DONE",
              whys[w], (long long)last_sample());
        CHECK(lr_core_state() == LR_STATE_CONFIGURED, "trip %u: configured again", whys[w]);
    }
    adc_vals[0] = 100; adc_vals[1] = 200;

    /* a CONFIGURE clears the limits: the next run without LIMITS does not trip */
    reset_all();
    size_t n = cfg_body(b, 1, LR_WAVE_CONSTANT, 1000, 200, 0, 0, 1024, 3072, 500, lv, 1);
    host_send(LR_CONFIGURE, 1, b, n);
    host_send(LR_LIMITS, 2, lb, limits_body(lb, LR_TRIP_SPEED, 0, 10, 0, 0));
    host_send(LR_CONFIGURE, 3, b, n);
    host_send(LR_START, 4, NULL, 0);
    lr_core_poll();
    run_ticks(300, 1);
    collect();
    CHECK(find(LR_DONE) >= 0 && find(LR_ERROR) < 0, "limits cleared by CONFIGURE");

    /* refused: a window upside down, a short body, limits while running */
    reset_all();
    host_send(LR_CONFIGURE, 1, b, n);
    host_send(LR_LIMITS, 2, lb, limits_body(lb, LR_TRIP_SPEED, 10, 0, 0, 0));
    host_send(LR_LIMITS, 3, lb, 5);
    host_send(LR_START, 4, NULL, 0);
    host_send(LR_LIMITS, 5, lb, limits_body(lb, LR_TRIP_SPEED, 0, 10, 0, 0));
    for (int i = 0; i < 8; i++) lr_core_poll();   /* (a poll reads at most 64 bytes) */
    collect();
    int codes[3] = {0, 0, 0}, m = 0;
    for (int i = 0; i < nmsgs && m < 3; i++) if (msgs[i].type == LR_ERROR) codes[m++] = msgs[i].body[0];
    CHECK(codes[0] == LR_ERR_BAD_CONFIG && codes[1] == LR_ERR_BAD_FRAME && codes[2] == LR_ERR_BUSY,
          "bad limits refused (%d %d %d)", codes[0], codes[1], codes[2]);
    run_ticks(300, 1);
    collect();
    CHECK(find(LR_DONE) >= 0, "the run plays on without limits");
}

static void test_estop(void)
{
    uint8_t b[128], lb[LR_LIMITS_LEN];
    uint16_t lv[1] = {2600};
    reset_all();
    t_estop = 0;
    size_t n = cfg_body(b, 0, LR_WAVE_CONSTANT, 1000, 100000, 0, 0, 1024, 3072, 500, lv, 1);
    host_send(LR_CONFIGURE, 1, b, n);
    host_send(LR_LIMITS, 2, lb, limits_body(lb, LR_TRIP_ESTOP, 0, 0, 0, 0));
    host_send(LR_START, 3, NULL, 0);
    for (int i = 0; i < 4; i++) lr_core_poll();
    run_ticks(50, 1);
    CHECK(dac_hw == 2600 && timer_on, "E-stop closed: the run plays");
    t_estop = 1;                       /* pressed */
    lr_core_tick();
    CHECK(dac_hw == 2048 && !timer_on, "E-stop: 0 V at the next tick (word %u)", dac_hw);
    run_ticks(20, 1);
    collect();
    int k = find(LR_ERROR);
    CHECK(k >= 0 && msgs[k].body[0] == LR_ERR_TRIP, "E-stop reported as a trip");
    /* latched: a new run is refused while pressed, and after release until a ZERO */
    nmsgs = 0;
    host_send(LR_CONFIGURE, 4, b, n);
    host_send(LR_START, 5, NULL, 0);
    for (int i = 0; i < 4; i++) lr_core_poll();
    t_estop = 0;
    host_send(LR_START, 6, NULL, 0);
    for (int i = 0; i < 4; i++) lr_core_poll();
    collect();
    int errs = 0;
    for (int i = 0; i < nmsgs; i++) if (msgs[i].type == LR_ERROR && msgs[i].body[0] == LR_ERR_TRIP) errs++;
    CHECK(errs == 2 && !timer_on, "latched: both STARTs refused (%d)", errs);
    host_send(LR_ZERO, 7, NULL, 0);
    host_send(LR_CONFIGURE, 8, b, n);
    host_send(LR_START, 9, NULL, 0);
    for (int i = 0; i < 6; i++) lr_core_poll();
    run_ticks(5, 1);
    CHECK(timer_on && dac_hw == 2600, "released and ZERO: the next run plays");
}

static void test_board_id(void)
{
    uint8_t b[4];
    reset_all();
    t_id = 0; t_id_writes = 0;
    host_send(LR_BOARD_ID, 1, NULL, 0);
    for (int i = 0; i < 3; i++) lr_core_poll();
    collect();
    int k = find(LR_ID);
    CHECK(k >= 0 && msgs[k].len == 4 && lr_get32(msgs[k].body) == 0, "no id yet: 0");
    nmsgs = 0;
    lr_put32(b, 0x3F2A91C0u);
    host_send(LR_BOARD_ID, 2, b, 4);
    for (int i = 0; i < 3; i++) lr_core_poll();
    collect();
    k = find(LR_ID);
    CHECK(k >= 0 && lr_get32(msgs[k].body) == 0x3F2A91C0u && t_id_writes == 1, "an id given is kept");
    nmsgs = 0;
    lr_put32(b, 0x11111111u);
    host_send(LR_BOARD_ID, 3, b, 4);
    for (int i = 0; i < 3; i++) lr_core_poll();
    collect();
    k = find(LR_ID);
    CHECK(k >= 0 && lr_get32(msgs[k].body) == 0x3F2A91C0u && t_id_writes == 1,
          "a given id is never replaced");
    nmsgs = 0;
    host_send(LR_BOARD_ID, 4, b, 3);
    for (int i = 0; i < 3; i++) lr_core_poll();
    collect();
    k = find(LR_ERROR);
    CHECK(k >= 0 && msgs[k].body[0] == LR_ERR_BAD_FRAME, "a 3-byte id is a bad frame");
}

/* the board's own loop on its sensors (the MS150 build, loop 2): at each sample, once its
 * words are in, out = dac_zero + floor((kp_q (ref - pos) - kd_q (tacho - tacho at rest))
 * / 256), clamped; the lead-in's reference is the host's; the sample records that output
 * and the reference */
static void test_board_loop(void)
{
    uint8_t b[128], lb[LR_LIMITS_LEN];
    uint16_t lv[1] = {600};
    reset_all();
    host_send(LR_HELLO_REQ, 9, NULL, 0);
    lr_core_poll(); collect();
    int k = find(LR_HELLO);
    CHECK(k >= 0 && (lr_get16(msgs[k].body + 2) & LR_CAP_BOARD_LOOP), "HELLO offers the board's loop");

    /* kp_q 1000, kd_q 100 (cfg_body's gains), lead-in 2 samples at word 512, tacho zero 512 */
    size_t n = cfg_body(b, LR_LOOP_BOARD, LR_WAVE_CONSTANT, 1000, 10, 2, 0, 1024, 3072, 500, lv, 1);
    lr_put16(b + n, 512); lr_put16(b + n + 2, 512);
    host_send(LR_CONFIGURE, 1, b, n);   /* without its tail: refused */
    host_send(LR_CONFIGURE, 2, b, n + 4);
    host_send(LR_START, 3, NULL, 0);
    for (int i = 0; i < 4; i++) lr_core_poll();
    collect();
    k = find(LR_ERROR);
    CHECK(k >= 0 && msgs[k].body[0] == LR_ERR_BAD_FRAME && lr_core_state() == LR_STATE_RUNNING,
          "loop 2 without its tail refused, with it running");
    adc_vals[0] = 520; adc_vals[1] = 500;
    lr_core_tick();   /* lead-in: e = 512 - 500, v = 8: (12000 - 800) >> 8 = 43 */
    CHECK(dac_hw == 2048 + 43, "lead-in: the loop holds the lead-in reference (word %u)", dac_hw);
    lr_core_tick();
    lr_core_tick();   /* e = 600 - 500: (100000 - 800) >> 8 = 387 */
    CHECK(dac_hw == 2048 + 387, "the PD on the sensors' words (word %u)", dac_hw);
    adc_vals[1] = 700;
    lr_core_tick();   /* e = -100: floor(-100800 / 256) = -394 */
    CHECK(dac_hw == 2048 - 394, "floor below zero (word %u)", dac_hw);
    adc_vals[1] = 0;
    lr_core_tick();   /* e = 600: far beyond the limit */
    CHECK(dac_hw == 3072, "clamped to dac_max (word %u)", dac_hw);
    adc_auto = 0;
    lr_core_tick();   /* conversions started, not in: the output holds */
    lr_core_tick();   /* overrun: nothing new read, nothing new written */
    CHECK(dac_hw == 3072, "an overrun holds the output (word %u)", dac_hw);
    adc_auto = 1; adc_pending = 0;
    lr_core_sample_done(520, 500, 0);
    CHECK(dac_hw == 2048 + 387, "the late sample's output (word %u)", dac_hw);
    for (int i = 0; i < 6; i++) { lr_core_tick(); now_ms++; lr_core_poll(); }
    collect();
    CHECK(dac_hw == 2048 && find(LR_DONE) >= 0, "0 V at the end (word %u)", dac_hw);
    uint32_t seen = 0, ok = 0;
    for (int i = 0; i < nmsgs; i++) {
        if (msgs[i].type != LR_SAMPLES) continue;
        for (int j = 0; j < msgs[i].body[4]; j++) {
            const uint8_t *p = msgs[i].body + 5 + j * LR_SAMPLE_BYTES;
            uint32_t idx = lr_get32(msgs[i].body) + (uint32_t)j;
            uint16_t want_ref = idx < 2 ? 512 : 600;
            uint16_t want_dac = idx < 2 ? 2048 + 43 : idx == 2 ? 2048 + 387 : idx == 3 ? 2048 - 394 : 0;
            seen++;
            if (lr_get16(p + 6) == want_ref && (!want_dac || lr_get16(p) == want_dac)) ok++;
        }
    }
    CHECK(seen >= 8 && ok == seen, "samples record the loop's output and reference (%u of %u)", ok, seen);

    /* a trip: the tripping sample's output is 0 V, not the PD's */
    reset_all();
    adc_vals[0] = 520; adc_vals[1] = 500;
    n = cfg_body(b, LR_LOOP_BOARD, LR_WAVE_CONSTANT, 1000, 1000, 0, 0, 1024, 3072, 500, lv, 1);
    lr_put16(b + n, 512); lr_put16(b + n + 2, 512);
    host_send(LR_CONFIGURE, 1, b, n + 4);
    host_send(LR_LIMITS, 2, lb, limits_body(lb, LR_TRIP_SPEED, 0, 600, 0, 0));
    host_send(LR_START, 3, NULL, 0);
    for (int i = 0; i < 3; i++) lr_core_poll();
    lr_core_tick();
    CHECK(dac_hw == 2048 + 387, "inside the limits: the PD's output");
    adc_vals[0] = 601;
    lr_core_tick();
    CHECK(dac_hw == 2048 && !timer_on, "over-speed under the board's loop: 0 V (word %u)", dac_hw);
    adc_vals[0] = 100; adc_vals[1] = 200;

    /* loop 2 is the MS150 build's: beyond it, a bad configure */
    n = cfg_body(b, 3, LR_WAVE_CONSTANT, 1000, 10, 0, 0, 1024, 3072, 500, lv, 1);
    CHECK(configure_error(b, n) == LR_ERR_BAD_CONFIG, "an unknown loop refused");
}

int main(int argc, char **argv)
{
    test_vectors(argc > 1 ? argv[1] : "test_vectors.json");
    test_hello_and_zero_at_reset();
    test_square_run();
    test_staircase();
    test_limits();
    test_watchdog();
    test_overrun_gap();
    test_stop_and_garbage();
    test_start_retransmission();
    test_fuzz();
    test_quadrature();
    test_index_latch();
    test_index_frames();
    test_drive_map();
    test_trips();
    test_estop();
    test_board_id();
    test_board_loop();
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}

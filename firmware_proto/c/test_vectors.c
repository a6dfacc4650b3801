/*
 * test_vectors.c - checks the C codec against every golden vector.
 *
 * The vectors are compiled in from vectors.inc, generated from firmware_proto/vectors/ (JSON)
 * by `python -m firmware_proto.golden c-table firmware_proto/c/vectors.inc`.
 * Each decode vector is run three ways: the whole input at once, one byte per call, and
 * split into two chunks at every position; all must give exactly the expected events
 * (canonical text, see test_support.c) and counters. Exit status 0 when all pass.
 *
 *   cc -std=c99 -Wall -Wextra -Werror -pedantic arva_codec.c test_support.c test_vectors.c -lm
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "arva_codec.h"
#include "test_support.h"

enum { ENC_PARVA, ENC_PARVH, ENC_EPOCH };

struct decode_vector {
    const char *name;
    const char *input;
    size_t input_len;
    int expect_fields;
    const char *events;
    const char *stats;
};

struct encode_vector {
    const char *name;
    int sentence;
    long args[6];
    double h[3];
    const arva_slot *slots;
    unsigned nslots;
    int valid;
    const char *bytes;
    size_t bytes_len;
};

#include "vectors.inc"

#define OUT_CAP 65536

static arva_decoder dec;
static char got[OUT_CAP];
static char stats[1024];

/* Appends the events produced so far to got[]; returns 0 on overflow. */
static int collect(const uint8_t *data, size_t len, size_t *pos)
{
    size_t w = arva_test_feed(&dec, data, len, got + *pos, OUT_CAP - *pos);
    if (w == (size_t)-1) {
        return 0;
    }
    *pos += w;
    return 1;
}

static int finish(size_t *pos)
{
    size_t w = arva_test_flush(&dec, got + *pos, OUT_CAP - *pos);
    if (w == (size_t)-1) {
        return 0;
    }
    *pos += w;
    return arva_test_stats(&dec, stats, sizeof stats) != (size_t)-1;
}

static int check(const struct decode_vector *v, const char *how)
{
    if (strcmp(got, v->events) != 0) {
        printf("FAIL %s (%s): events differ\n--- expected\n%s--- got\n%s", v->name, how, v->events, got);
        return 0;
    }
    if (strcmp(stats, v->stats) != 0) {
        printf("FAIL %s (%s): counters differ\n  expected %s\n  got      %s\n", v->name, how, v->stats, stats);
        return 0;
    }
    return 1;
}

static int run_decode(const struct decode_vector *v)
{
    const uint8_t *in = (const uint8_t *)v->input;
    size_t pos, i, cut;

    /* 1. all at once */
    arva_decoder_init(&dec, v->expect_fields);
    pos = 0;
    got[0] = '\0';
    if (!collect(in, v->input_len, &pos) || !finish(&pos) || !check(v, "one chunk")) {
        return 0;
    }
    /* 2. one byte per call */
    arva_decoder_init(&dec, v->expect_fields);
    pos = 0;
    got[0] = '\0';
    for (i = 0; i < v->input_len; i++) {
        if (!collect(in + i, 1, &pos)) {
            return 0;
        }
    }
    if (!finish(&pos) || !check(v, "byte by byte")) {
        return 0;
    }
    /* 3. two chunks, every cut */
    for (cut = 1; cut < v->input_len; cut++) {
        char how[64];
        arva_decoder_init(&dec, v->expect_fields);
        pos = 0;
        got[0] = '\0';
        if (!collect(in, cut, &pos) || !collect(in + cut, v->input_len - cut, &pos) || !finish(&pos)) {
            return 0;
        }
        snprintf(how, sizeof how, "cut at %lu", (unsigned long)cut);
        if (!check(v, how)) {
            return 0;
        }
    }
    return 1;
}

static int run_encode(const struct encode_vector *v)
{
    char out[ARVA_MAX_SENTENCE * ARVA_PROTOCOL_MAX_CHANNELS + 1];
    size_t n = 0;
    if (v->sentence == ENC_PARVA) {
        arva_slot s;
        s.id = (int32_t)v->args[3];
        s.d = (int32_t)v->args[4];
        s.delta = (int32_t)v->args[5];
        n = arva_encode_parva(out, sizeof out, (uint32_t)v->args[0], (unsigned)v->args[1], (unsigned)v->args[2], s);
    } else if (v->sentence == ENC_PARVH) {
        char h[3][64];
        int i;
        for (i = 0; i < 3; i++) {
            snprintf(h[i], sizeof h[i], "%.6e", v->h[i]);
        }
        n = arva_encode_parvh(out, sizeof out, (uint32_t)v->args[0], (unsigned)v->args[1], (int32_t)v->args[2], h[0],
                              h[1], h[2]);
    } else {
        n = arva_encode_epoch(out, sizeof out, (uint32_t)v->args[0], v->slots, v->nslots);
    }
    if (!v->valid) {
        if (n != 0) {
            printf("FAIL encode %s: accepted, should be refused\n", v->name);
            return 0;
        }
        return 1;
    }
    if (n != v->bytes_len || memcmp(out, v->bytes, n) != 0) {
        printf("FAIL encode %s: got %lu bytes '%.*s', expected '%s'\n", v->name, (unsigned long)n, (int)n, out,
               v->bytes);
        return 0;
    }
    /* A buffer one byte short must be refused, never overrun. */
    if (v->sentence == ENC_PARVA) {
        arva_slot s;
        s.id = (int32_t)v->args[3];
        s.d = (int32_t)v->args[4];
        s.delta = (int32_t)v->args[5];
        if (arva_encode_parva(out, n - 1, (uint32_t)v->args[0], (unsigned)v->args[1], (unsigned)v->args[2], s) != 0) {
            printf("FAIL encode %s: wrote into a buffer that is too small\n", v->name);
            return 0;
        }
    }
    return 1;
}

int main(void)
{
    size_t i, failed = 0;
    size_t nd = sizeof DECODE_VECTORS / sizeof DECODE_VECTORS[0];
    size_t ne = sizeof ENCODE_VECTORS / sizeof ENCODE_VECTORS[0];
    for (i = 0; i < nd; i++) {
        if (!run_decode(&DECODE_VECTORS[i])) {
            failed++;
        }
    }
    for (i = 0; i < ne; i++) {
        if (!run_encode(&ENCODE_VECTORS[i])) {
            failed++;
        }
    }
    printf("%lu decode + %lu encode vectors, %lu failed\n", (unsigned long)nd, (unsigned long)ne,
           (unsigned long)failed);
    return failed == 0 ? 0 : 1;
}

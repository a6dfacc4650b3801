/*
 * test_support.c - NOT part of the codec: helpers for the golden-vector runner and the
 * Python cross-check (ctypes). Uses stdio/stdlib/floating point, which the codec does not.
 *
 * Every event becomes one canonical text line, the same text firmware_proto/golden.py
 * produces for the Python decoder, so the two implementations are compared line by line:
 *   parva OFFSET SEQ N K ID D DELTA
 *   parvh OFFSET SEQ K ID HX HY HZ               (components as %.17g of their double)
 *   error KIND OFFSET LENGTH
 *   epoch SEQ N COMPLETE GAP ID,D,DELTA;-;...[ HX,HY,HZ;-;...]
 *   stats bytes=.. garbage_bytes=.. ... errors.KIND=.. ...
 */
#include "test_support.h"

#include <stdio.h>
#include <stdlib.h>

/* New length after snprintf wrote n chars at pos, or -1 if they did not fit. */
static size_t advance(size_t cap, size_t pos, int n)
{
    if (n < 0 || pos + (size_t)n >= cap) {
        return (size_t)-1;
    }
    return pos + (size_t)n;
}

#define APPEND(...)                                                                   \
    do {                                                                              \
        pos = advance(cap, pos, snprintf(out + pos, cap - pos, __VA_ARGS__));         \
        if (pos == (size_t)-1) {                                                      \
            return (size_t)-1;                                                        \
        }                                                                             \
    } while (0)

static double text_value(const char *s)
{
    return strtod(s, 0);
}

size_t arva_describe_event(const arva_event *ev, char *out, size_t cap)
{
    size_t pos = 0;
    unsigned k;
    switch (ev->type) {
    case ARVA_EV_PARVA:
        APPEND("parva %lu %u %u %u %ld %ld %ld", (unsigned long)ev->offset, (unsigned)ev->s.parva.seq,
               (unsigned)ev->s.parva.n, (unsigned)ev->s.parva.k, (long)ev->s.parva.slot.id, (long)ev->s.parva.slot.d,
               (long)ev->s.parva.slot.delta);
        break;
    case ARVA_EV_PARVH:
        APPEND("parvh %lu %u %u %ld %.17g %.17g %.17g", (unsigned long)ev->offset, (unsigned)ev->s.parvh.seq,
               (unsigned)ev->s.parvh.k, (long)ev->s.parvh.id, text_value(ev->s.parvh.h[0]),
               text_value(ev->s.parvh.h[1]), text_value(ev->s.parvh.h[2]));
        break;
    case ARVA_EV_ERROR:
        APPEND("error %s %lu %u", arva_error_name(ev->kind), (unsigned long)ev->offset, (unsigned)ev->length);
        break;
    case ARVA_EV_EPOCH: {
        const arva_epoch *ep = ev->epoch;
        APPEND("epoch %u %u %u %u ", (unsigned)ep->seq, (unsigned)ep->n, (unsigned)ep->complete, (unsigned)ep->gap);
        for (k = 0; k < ep->n; k++) {
            if (k > 0) {
                APPEND(";");
            }
            if (ep->present[k]) {
                APPEND("%ld,%ld,%ld", (long)ep->slot[k].id, (long)ep->slot[k].d, (long)ep->slot[k].delta);
            } else {
                APPEND("-");
            }
        }
        if (ep->has_fields) {
            APPEND(" ");
            for (k = 0; k < ep->n; k++) {
                if (k > 0) {
                    APPEND(";");
                }
#if ARVA_WITH_FIELDS
                if (ep->field_present[k]) {
                    APPEND("%.17g,%.17g,%.17g", text_value(ep->field[k][0]), text_value(ep->field[k][1]),
                           text_value(ep->field[k][2]));
                } else {
                    APPEND("-");
                }
#else
                APPEND("%s", ep->field_present[k] ? "?" : "-");
#endif
            }
        }
        break;
    }
    default:
        APPEND("none");
        break;
    }
    return pos;
}

size_t arva_describe_stats(const arva_stats *st, char *out, size_t cap)
{
    size_t pos = 0;
    int kind;
    APPEND("stats bytes=%lu garbage_bytes=%lu sentences_ok=%lu epochs_complete=%lu epochs_incomplete=%lu "
           "seq_gaps=%lu seqs_missing=%lu seq_wraps=%lu fields_orphaned=%lu",
           (unsigned long)st->bytes, (unsigned long)st->garbage_bytes, (unsigned long)st->sentences_ok,
           (unsigned long)st->epochs_complete, (unsigned long)st->epochs_incomplete, (unsigned long)st->seq_gaps,
           (unsigned long)st->seqs_missing, (unsigned long)st->seq_wraps, (unsigned long)st->fields_orphaned);
    for (kind = 1; kind < ARVA_ERROR_KINDS; kind++) {
        APPEND(" errors.%s=%lu", arva_error_name((arva_error_kind)kind), (unsigned long)st->errors[kind]);
    }
    return pos;
}

size_t arva_test_decoder_size(void)
{
    return sizeof(arva_decoder);
}

/* Collects every queued/produced event as lines ("...\n") into out; -1 if out is full. */
static size_t drain(arva_decoder *dec, const uint8_t *data, size_t len, char *out, size_t cap)
{
    size_t pos = 0;
    arva_event ev;
    const uint8_t *p = data;
    size_t n = len;
    while (arva_decoder_next(dec, &p, &n, &ev)) {
        size_t w;
        if (pos + 2 >= cap) {
            return (size_t)-1;
        }
        w = arva_describe_event(&ev, out + pos, cap - pos - 1);
        if (w == (size_t)-1) {
            return (size_t)-1;
        }
        pos += w;
        out[pos++] = '\n';
        out[pos] = '\0';
    }
    if (pos < cap) {
        out[pos] = '\0';
    }
    return pos;
}

size_t arva_test_feed(arva_decoder *dec, const uint8_t *data, size_t len, char *out, size_t cap)
{
    return drain(dec, data, len, out, cap);
}

size_t arva_test_flush(arva_decoder *dec, char *out, size_t cap)
{
    if (arva_decoder_flush(dec) != 0) {
        return (size_t)-1;
    }
    return drain(dec, 0, 0, out, cap);
}

size_t arva_test_idle(arva_decoder *dec, char *out, size_t cap)
{
    if (arva_decoder_idle(dec) != 0) {
        return (size_t)-1;
    }
    return drain(dec, 0, 0, out, cap);
}

size_t arva_test_stats(const arva_decoder *dec, char *out, size_t cap)
{
    return arva_describe_stats(&dec->stats, out, cap);
}

/* Counts sentences only (for the throughput benchmark): no text, no copies. */
unsigned long arva_test_count(arva_decoder *dec, const uint8_t *data, size_t len)
{
    unsigned long sentences = 0;
    arva_event ev;
    const uint8_t *p = data;
    size_t n = len;
    while (arva_decoder_next(dec, &p, &n, &ev)) {
        if (ev.type == ARVA_EV_PARVA || ev.type == ARVA_EV_PARVH) {
            sentences++;
        }
    }
    return sentences;
}

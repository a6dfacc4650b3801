/* test_support.h - test-only helpers around the codec (see test_support.c). */
#ifndef ARVA_TEST_SUPPORT_H
#define ARVA_TEST_SUPPORT_H

#include "arva_codec.h"

/* One canonical text line (no newline) for an event / the counters; returns its length,
 * or (size_t)-1 when it does not fit in cap (NUL included). */
size_t arva_describe_event(const arva_event *ev, char *out, size_t cap);
size_t arva_describe_stats(const arva_stats *st, char *out, size_t cap);

/* ctypes entry points: decode and describe every event produced, one line each. */
size_t arva_test_decoder_size(void);
size_t arva_test_feed(arva_decoder *dec, const uint8_t *data, size_t len, char *out, size_t cap);
size_t arva_test_flush(arva_decoder *dec, char *out, size_t cap);
size_t arva_test_idle(arva_decoder *dec, char *out, size_t cap);
size_t arva_test_stats(const arva_decoder *dec, char *out, size_t cap);
unsigned long arva_test_count(arva_decoder *dec, const uint8_t *data, size_t len);

#endif

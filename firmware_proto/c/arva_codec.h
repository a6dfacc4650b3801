/*
 * arva_codec.h - portable C99 codec for the ARVA receiver sentences $PARVA / $PARVH.
 *
 * No malloc, no stdio, no floating point: all state lives in caller-provided structs of
 * fixed size. The decoder is the same byte-level machine as the Python reference
 * (firmware_proto/decoder.py): same events, same error kinds, same counters, checked
 * against the golden vectors in firmware_proto/vectors/. See docs/protocol.md.
 *
 * Build: add arva_codec.c to your firmware; compile as C99 (or later, or C++).
 * Size knobs (define before including, identically for every translation unit):
 *   ARVA_MAX_CHANNELS   largest n accepted (default 99, the protocol limit); a smaller
 *                       value makes $PARVA/$PARVH with n or k above it OUT_OF_RANGE.
 *   ARVA_WITH_FIELDS    1 (default): epochs keep the $PARVH text of each slot;
 *                       0: $PARVH is still validated and reported, its text is not kept.
 * sizeof(arva_decoder) with the defaults is about 23 KB (two epoch buffers holding field
 * text for 99 slots); with ARVA_MAX_CHANNELS 4 and ARVA_WITH_FIELDS 0 about 720 bytes.
 */
#ifndef ARVA_CODEC_H
#define ARVA_CODEC_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#ifndef ARVA_MAX_CHANNELS
#define ARVA_MAX_CHANNELS 99
#endif
#ifndef ARVA_WITH_FIELDS
#define ARVA_WITH_FIELDS 1
#endif

#define ARVA_MAX_SENTENCE 82     /* bytes, '$' and CR LF included */
#define ARVA_SEQ_MODULO 65536L
#define ARVA_PROTOCOL_MAX_CHANNELS 99
#define ARVA_MAX_ID 65535L
#define ARVA_MAX_D_CM 9999999L
#define ARVA_MAX_ABS_DELTA 89
#define ARVA_FIELD_TEXT_MAX 32   /* longest $PARVH component text accepted */

#if ARVA_MAX_CHANNELS < 1 || ARVA_MAX_CHANNELS > ARVA_PROTOCOL_MAX_CHANNELS
#error "ARVA_MAX_CHANNELS must be within 1..99"
#endif

/* Why a sentence was rejected. Same names and numbers as the Python ErrorKind. */
typedef enum {
    ARVA_OK = 0,
    ARVA_BAD_CHECKSUM = 1,     /* well-formed frame, XOR of the body differs from *hh */
    ARVA_TOO_LONG = 2,         /* 82 bytes without the closing LF */
    ARVA_NON_ASCII = 3,        /* byte outside 0x20..0x7E (other than CR/LF) in a sentence */
    ARVA_MALFORMED = 4,        /* framing, field count or field syntax */
    ARVA_OUT_OF_RANGE = 5,     /* valid numbers outside the protocol limits */
    ARVA_UNKNOWN_SENTENCE = 6, /* valid frame, address not PARVA / PARVH */
    ARVA_TRUNCATED = 7         /* '$' or end of stream before the sentence's LF */
} arva_error_kind;
#define ARVA_ERROR_KINDS 8

/* One slot: (id, d [cm], delta [deg]); empty is (-1, -1, -1). */
typedef struct {
    int32_t id;
    int32_t d;
    int32_t delta;
} arva_slot;

/* ---------------------------------------------------------------- encoder ---------- */

/* XOR of n bytes (the checksum of a sentence body). */
uint8_t arva_checksum(const char *body, size_t n);

/* Writes "$PARVA,seq,n,k,id,d,delta*hh\r\n" (no NUL) into out; returns its length, or 0
 * when a value is outside the protocol limits or cap is too small. seq in 0..65535. */
size_t arva_encode_parva(char *out, size_t cap, uint32_t seq, unsigned n, unsigned k, arva_slot slot);

/* Writes every $PARVA of one epoch (seq is reduced modulo 65536); returns the total
 * length, or 0 (nothing usable written) on a bad value or a too small buffer. */
size_t arva_encode_epoch(char *out, size_t cap, uint32_t seq, const arva_slot *slots, unsigned n);

/* Writes "$PARVH,seq,k,id,hx,hy,hz*hh\r\n". The components are NUL-terminated text the
 * caller formatted (e.g. "%.6e", or fixed point written by hand); each must be a finite
 * decimal number (see docs/protocol.md) of at most ARVA_FIELD_TEXT_MAX characters.
 * Returns the length, or 0 on a bad value, an over-long sentence or a small buffer. */
size_t arva_encode_parvh(char *out, size_t cap, uint32_t seq, unsigned k, int32_t id, const char *hx,
                         const char *hy, const char *hz);

/* ---------------------------------------------------------------- decoder ---------- */

typedef struct {
    uint16_t seq;
    uint8_t n;
    uint8_t k;
    arva_slot slot;
} arva_parva;

typedef struct {
    uint16_t seq;
    uint8_t k;
    int32_t id;
    char h[3][ARVA_FIELD_TEXT_MAX + 1]; /* NUL-terminated component text, as received */
} arva_parvh;

typedef struct {
    uint16_t seq;
    uint8_t n;
    uint8_t complete;  /* every slot arrived, no rejected sentence in between */
    uint16_t gap;      /* seq values skipped before this epoch (mod 65536) */
    uint8_t present[ARVA_MAX_CHANNELS];       /* slot k-1 arrived intact */
    arva_slot slot[ARVA_MAX_CHANNELS];
    uint8_t has_fields;                        /* some $PARVH attached */
    uint8_t field_present[ARVA_MAX_CHANNELS];  /* $PARVH of slot k-1 attached */
#if ARVA_WITH_FIELDS
    char field[ARVA_MAX_CHANNELS][3][ARVA_FIELD_TEXT_MAX + 1];
#endif
} arva_epoch;

typedef enum {
    ARVA_EV_NONE = 0,
    ARVA_EV_PARVA = 1,
    ARVA_EV_PARVH = 2,
    ARVA_EV_ERROR = 3,
    ARVA_EV_EPOCH = 4
} arva_event_type;

typedef struct {
    arva_event_type type;
    uint32_t offset;        /* PARVA/PARVH/ERROR: stream offset of the '$' (mod 2^32) */
    uint16_t length;        /* ERROR: bytes consumed by the rejected sentence */
    arva_error_kind kind;   /* ERROR */
    union {
        arva_parva parva;   /* PARVA */
        arva_parvh parvh;   /* PARVH */
    } s;
    const arva_epoch *epoch; /* EPOCH: valid until the next call into this decoder */
} arva_event;

typedef struct {
    uint32_t bytes;
    uint32_t garbage_bytes;
    uint32_t sentences_ok;
    uint32_t errors[ARVA_ERROR_KINDS]; /* indexed by arva_error_kind; [0] unused */
    uint32_t epochs_complete;
    uint32_t epochs_incomplete;
    uint32_t seq_gaps;
    uint32_t seqs_missing;
    uint32_t seq_wraps;      /* epochs whose seq is below the previous one (65535 -> 0, or a restart) */
    uint32_t fields_orphaned;
} arva_stats;

/* All decoder state; treat as opaque except `stats`. */
typedef struct {
    arva_stats stats;
    /* framing */
    uint8_t line[ARVA_MAX_SENTENCE];
    uint8_t len;          /* bytes of the open sentence; 0 = outside a sentence */
    uint32_t start;       /* offset of its '$' */
    uint32_t offset;      /* offset of the next byte */
    /* epoch assembly */
    arva_epoch ep[2];
    uint8_t cur;          /* ep[cur] is the epoch being assembled */
    uint8_t pending;      /* ep[cur] holds at least one slot */
    uint8_t holding;      /* ep[cur] is complete, waiting one sentence for its $PARVH */
    uint8_t tainted;
    uint8_t last_k;
    uint8_t expect_fields;
    uint8_t have_last_seq;
    uint16_t last_seq;
    int32_t max_d_cm;     /* readings beyond it are OUT_OF_RANGE (arva_decoder_set_max_range) */
    /* events produced but not yet returned */
    arva_event queue[3];
    uint8_t qhead;
    uint8_t qlen;
} arva_decoder;

/* Resets everything. expect_fields: hold each epoch for a possible $PARVH of its last
 * slot from the start (otherwise that starts with the first $PARVH seen). */
void arva_decoder_init(arva_decoder *dec, int expect_fields);

/* Plausibility check on top of the XOR checksum (docs/protocol.md, "What the checksum
 * misses"): reject as OUT_OF_RANGE every $PARVA whose d exceeds max_d_cm, the receiver's
 * maximum range (e.g. 5000 for r_outer = 50 m). Default after init: ARVA_MAX_D_CM (no
 * extra check). Returns 0, or -1 (and changes nothing) for a value outside 0..ARVA_MAX_D_CM. */
int arva_decoder_set_max_range(arva_decoder *dec, long max_d_cm);

/* Consumes bytes from *data / *len (advancing both) until one event is ready, then
 * stores it in *ev and returns 1; returns 0 when all input is consumed and no event is
 * pending. data may be NULL (or *len 0) to only collect queued events. Typical use:
 *     while (arva_decoder_next(&dec, &p, &n, &ev)) handle(&ev);            */
int arva_decoder_next(arva_decoder *dec, const uint8_t **data, size_t *len, arva_event *ev);

/* End of stream: an open sentence becomes TRUNCATED and the pending epoch is emitted.
 * Collect the events with arva_decoder_next(dec, NULL, NULL, &ev). Returns -1 (and does
 * nothing) unless every earlier event has been collected. */
int arva_decoder_flush(arva_decoder *dec);

/* The line went quiet (e.g. no byte for 100 ms): release an epoch held for its last
 * $PARVH. Same calling rule and return value as arva_decoder_flush. */
int arva_decoder_idle(arva_decoder *dec);

/* Upper-case name of an error kind ("BAD_CHECKSUM", ...), "OK" for 0, "?" otherwise. */
const char *arva_error_name(arva_error_kind kind);

#ifdef __cplusplus
}
#endif

#endif /* ARVA_CODEC_H */

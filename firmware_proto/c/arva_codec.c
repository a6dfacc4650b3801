/*
 * arva_codec.c - portable C99 codec for $PARVA / $PARVH. See arva_codec.h.
 *
 * Mirrors firmware_proto/decoder.py (framing, parse_line) and firmware_proto/epochs.py
 * (epoch assembly) rule for rule; the comments name the rule, the Python side explains it.
 */
#include "arva_codec.h"

/* ------------------------------------------------------------------ helpers -------- */

static const char HEX[] = "0123456789ABCDEF";

/* 2^1024 - 2^970: decimal numbers at or above this round to infinity as a double. */
static const char DBL_OVERFLOW_DIGITS[] = "179769313486231580793728971405303415079934132";
#define DBL_OVERFLOW_EXP10 308

uint8_t arva_checksum(const char *body, size_t n)
{
    uint8_t x = 0;
    size_t i;
    for (i = 0; i < n; i++) {
        x ^= (uint8_t)body[i];
    }
    return x;
}

/* Appends the decimal text of v at out[*pos] if it fits below cap. */
static int put_int(char *out, size_t cap, size_t *pos, long v)
{
    char tmp[12];
    size_t n = 0;
    unsigned long u = v < 0 ? 0UL - (unsigned long)v : (unsigned long)v;
    if (v < 0) {
        if (*pos >= cap) {
            return 0;
        }
        out[(*pos)++] = '-';
    }
    do {
        tmp[n++] = (char)('0' + (u % 10UL));
        u /= 10UL;
    } while (u != 0UL);
    if (cap - *pos < n) {
        return 0;
    }
    while (n > 0) {
        out[(*pos)++] = tmp[--n];
    }
    return 1;
}

static int put_text(char *out, size_t cap, size_t *pos, const char *s, size_t n)
{
    size_t i;
    if (cap - *pos < n) {
        return 0;
    }
    for (i = 0; i < n; i++) {
        out[(*pos)++] = s[i];
    }
    return 1;
}

/* Closes a sentence whose body is out[1 .. *pos-1]: "*hh\r\n". */
static size_t put_tail(char *out, size_t cap, size_t pos)
{
    uint8_t cs;
    if (cap - pos < 5 || pos + 5 > ARVA_MAX_SENTENCE) {
        return 0;
    }
    cs = arva_checksum(out + 1, pos - 1);
    out[pos++] = '*';
    out[pos++] = HEX[cs >> 4];
    out[pos++] = HEX[cs & 0x0F];
    out[pos++] = '\r';
    out[pos++] = '\n';
    return pos;
}

static int slot_ok(long id, long d, long delta)
{
    if (id == -1 && d == -1 && delta == -1) {
        return 1;
    }
    return id >= 0 && id <= ARVA_MAX_ID && d >= 0 && d <= ARVA_MAX_D_CM && delta >= -ARVA_MAX_ABS_DELTA &&
           delta <= ARVA_MAX_ABS_DELTA;
}

/* Integer field: "0" | "-"? [1-9][0-9]*. Returns 1 if the syntax is valid; *v gets the
 * value, or +/-1000000000 for anything longer than 9 digits (outside every limit). */
static int parse_int(const uint8_t *p, size_t n, long *v)
{
    size_t i = 0;
    int neg = 0;
    long acc = 0;
    if (n == 0) {
        return 0;
    }
    if (p[0] == '-') {
        neg = 1;
        i = 1;
        if (n == 1) {
            return 0;
        }
    }
    if (p[i] == '0') {
        if (neg || n != 1) {
            return 0; /* "-0", leading zero */
        }
        *v = 0;
        return 1;
    }
    for (; i < n; i++) {
        if (p[i] < '0' || p[i] > '9') {
            return 0;
        }
        if (acc < 1000000000L) {
            acc = acc * 10 + (long)(p[i] - '0');
        }
    }
    if (acc > 1000000000L || n - (size_t)neg > 9) {
        acc = 1000000000L;
    }
    *v = neg ? -acc : acc;
    return 1;
}

/* $PARVH component: "-"? D+ ("." D+)? ([eE] [+-]? D+)?, at most ARVA_FIELD_TEXT_MAX
 * chars. Returns 0 malformed, 1 finite, 2 valid syntax but overflows a double. */
static int check_float(const uint8_t *p, size_t n)
{
    size_t i = 0, int_digits = 0, frac_digits = 0, first_nz = 0, k;
    int seen_nz = 0, exp_neg = 0;
    long e = 0, exp10;
    const uint8_t *mant = 0;
    if (n == 0 || n > ARVA_FIELD_TEXT_MAX) {
        return 0;
    }
    if (p[i] == '-') {
        i++;
    }
    mant = p + i;
    while (i < n && p[i] >= '0' && p[i] <= '9') {
        i++;
        int_digits++;
    }
    if (int_digits == 0) {
        return 0;
    }
    if (i < n && p[i] == '.') {
        i++;
        while (i < n && p[i] >= '0' && p[i] <= '9') {
            i++;
            frac_digits++;
        }
        if (frac_digits == 0) {
            return 0;
        }
    }
    if (i < n && (p[i] == 'e' || p[i] == 'E')) {
        size_t exp_digits = 0;
        i++;
        if (i < n && (p[i] == '+' || p[i] == '-')) {
            exp_neg = p[i] == '-';
            i++;
        }
        while (i < n && p[i] >= '0' && p[i] <= '9') {
            if (e < 100000L) {
                e = e * 10 + (long)(p[i] - '0');
            }
            i++;
            exp_digits++;
        }
        if (exp_digits == 0) {
            return 0;
        }
    }
    if (i != n) {
        return 0;
    }
    if (exp_neg) {
        e = -e;
    }
    /* Magnitude check on the digits (mantissa digits with the '.' skipped). */
    {
        size_t total = int_digits + frac_digits;
        size_t idx = 0;
        const uint8_t *q = mant;
        uint8_t digits[ARVA_FIELD_TEXT_MAX];
        for (k = 0; idx < total; k++) {
            if (q[k] != '.') {
                digits[idx++] = q[k];
            }
        }
        for (k = 0; k < total; k++) {
            if (digits[k] != '0') {
                seen_nz = 1;
                first_nz = k;
                break;
            }
        }
        if (!seen_nz) {
            return 1; /* zero */
        }
        exp10 = (long)int_digits - 1L - (long)first_nz + e;
        if (exp10 < DBL_OVERFLOW_EXP10) {
            return 1;
        }
        if (exp10 > DBL_OVERFLOW_EXP10) {
            return 2;
        }
        for (k = first_nz; k < total; k++) {
            char m = DBL_OVERFLOW_DIGITS[k - first_nz];
            if ((char)digits[k] < m) {
                return 1;
            }
            if ((char)digits[k] > m) {
                return 2;
            }
        }
        return 1; /* a proper prefix of the threshold's digits: below it */
    }
}

static size_t cstrlen(const char *s)
{
    size_t n = 0;
    while (s[n] != '\0') {
        n++;
    }
    return n;
}

/* ------------------------------------------------------------------ encoder -------- */

size_t arva_encode_parva(char *out, size_t cap, uint32_t seq, unsigned n, unsigned k, arva_slot slot)
{
    size_t pos = 0;
    if (out == 0 || seq >= (uint32_t)ARVA_SEQ_MODULO || n < 1 || n > ARVA_PROTOCOL_MAX_CHANNELS || k < 1 ||
        k > n || !slot_ok((long)slot.id, (long)slot.d, (long)slot.delta)) {
        return 0;
    }
    if (!put_text(out, cap, &pos, "$PARVA,", 7) || !put_int(out, cap, &pos, (long)seq) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)n) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)k) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)slot.id) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)slot.d) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)slot.delta)) {
        return 0;
    }
    return put_tail(out, cap, pos);
}

size_t arva_encode_epoch(char *out, size_t cap, uint32_t seq, const arva_slot *slots, unsigned n)
{
    size_t total = 0;
    unsigned k;
    if (slots == 0 || n < 1 || n > ARVA_PROTOCOL_MAX_CHANNELS) {
        return 0;
    }
    seq %= (uint32_t)ARVA_SEQ_MODULO;
    for (k = 1; k <= n; k++) {
        size_t w = arva_encode_parva(out + total, cap - total, seq, n, k, slots[k - 1]);
        if (w == 0) {
            return 0;
        }
        total += w;
    }
    return total;
}

size_t arva_encode_parvh(char *out, size_t cap, uint32_t seq, unsigned k, int32_t id, const char *hx,
                         const char *hy, const char *hz)
{
    const char *h[3];
    size_t pos = 0;
    int i;
    h[0] = hx;
    h[1] = hy;
    h[2] = hz;
    if (out == 0 || seq >= (uint32_t)ARVA_SEQ_MODULO || k < 1 || k > ARVA_PROTOCOL_MAX_CHANNELS ||
        !(id == -1 || (id >= 0 && id <= ARVA_MAX_ID))) {
        return 0;
    }
    for (i = 0; i < 3; i++) {
        if (h[i] == 0) {
            return 0;
        }
        {
            size_t len = cstrlen(h[i]);
            if (len > ARVA_FIELD_TEXT_MAX || check_float((const uint8_t *)h[i], len) != 1) {
                return 0;
            }
        }
    }
    if (!put_text(out, cap, &pos, "$PARVH,", 7) || !put_int(out, cap, &pos, (long)seq) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)k) ||
        !put_text(out, cap, &pos, ",", 1) || !put_int(out, cap, &pos, (long)id)) {
        return 0;
    }
    for (i = 0; i < 3; i++) {
        if (!put_text(out, cap, &pos, ",", 1) || !put_text(out, cap, &pos, h[i], cstrlen(h[i]))) {
            return 0;
        }
    }
    return put_tail(out, cap, pos);
}

/* ------------------------------------------------------------------ parser --------- */

typedef struct {
    arva_error_kind kind; /* ARVA_OK: sentence valid */
    int is_parvh;
    arva_parva parva;
    arva_parvh parvh;
} parse_result;

static int hex_value(uint8_t c)
{
    if (c >= '0' && c <= '9') {
        return c - '0';
    }
    if (c >= 'A' && c <= 'F') {
        return c - 'A' + 10;
    }
    return -1; /* lower case is rejected on purpose */
}

/* line[0..len-1]: '$' ... '\n', len <= 82, framing guarantees the rest (see decoder.py). */
static void parse_line(const uint8_t *line, size_t len, long max_d_cm, parse_result *r)
{
    const uint8_t *body = line + 1;
    size_t blen, i, ntok = 0;
    const uint8_t *tok[7];
    size_t toklen[7];
    int hi, lo, is_a, is_h;
    long v[6];
    size_t start;

    r->kind = ARVA_MALFORMED;
    if (len < 6 || line[len - 2] != '\r' || line[len - 5] != '*') {
        return;
    }
    hi = hex_value(line[len - 4]);
    lo = hex_value(line[len - 3]);
    if (hi < 0 || lo < 0) {
        return;
    }
    blen = len - 6;
    if (arva_checksum((const char *)body, blen) != (uint8_t)(hi * 16 + lo)) {
        r->kind = ARVA_BAD_CHECKSUM;
        return;
    }
    /* Address = body up to the first ',' (or all of it). */
    for (i = 0; i < blen && body[i] != ','; i++) {
    }
    is_a = i == 5 && body[0] == 'P' && body[1] == 'A' && body[2] == 'R' && body[3] == 'V' && body[4] == 'A';
    is_h = i == 5 && body[0] == 'P' && body[1] == 'A' && body[2] == 'R' && body[3] == 'V' && body[4] == 'H';
    if (!is_a && !is_h) {
        r->kind = ARVA_UNKNOWN_SENTENCE;
        return;
    }
    /* Split into exactly 7 tokens. */
    start = 0;
    for (i = 0; i <= blen; i++) {
        if (i == blen || body[i] == ',') {
            if (ntok == 7) {
                return; /* MALFORMED: too many fields */
            }
            tok[ntok] = body + start;
            toklen[ntok] = i - start;
            ntok++;
            start = i + 1;
        }
    }
    if (ntok != 7) {
        return;
    }
    if (is_a) {
        for (i = 0; i < 6; i++) {
            if (!parse_int(tok[i + 1], toklen[i + 1], &v[i])) {
                return;
            }
        }
        if (v[0] < 0 || v[0] >= ARVA_SEQ_MODULO || v[1] < 1 || v[1] > ARVA_MAX_CHANNELS || v[2] < 1 || v[2] > v[1] ||
            !slot_ok(v[3], v[4], v[5]) || v[4] > max_d_cm) {
            r->kind = ARVA_OUT_OF_RANGE;
            return;
        }
        r->is_parvh = 0;
        r->parva.seq = (uint16_t)v[0];
        r->parva.n = (uint8_t)v[1];
        r->parva.k = (uint8_t)v[2];
        r->parva.slot.id = (int32_t)v[3];
        r->parva.slot.d = (int32_t)v[4];
        r->parva.slot.delta = (int32_t)v[5];
        r->kind = ARVA_OK;
        return;
    }
    {
        int fin[3];
        for (i = 0; i < 3; i++) {
            if (!parse_int(tok[i + 1], toklen[i + 1], &v[i])) {
                return;
            }
        }
        for (i = 0; i < 3; i++) {
            fin[i] = check_float(tok[i + 4], toklen[i + 4]);
            if (fin[i] == 0) {
                return;
            }
        }
        if (v[0] < 0 || v[0] >= ARVA_SEQ_MODULO || v[1] < 1 || v[1] > ARVA_MAX_CHANNELS ||
            !(v[2] == -1 || (v[2] >= 0 && v[2] <= ARVA_MAX_ID)) || fin[0] != 1 || fin[1] != 1 || fin[2] != 1) {
            r->kind = ARVA_OUT_OF_RANGE;
            return;
        }
        r->is_parvh = 1;
        r->parvh.seq = (uint16_t)v[0];
        r->parvh.k = (uint8_t)v[1];
        r->parvh.id = (int32_t)v[2];
        for (i = 0; i < 3; i++) {
            size_t j;
            for (j = 0; j < toklen[i + 4]; j++) {
                r->parvh.h[i][j] = (char)tok[i + 4][j];
            }
            r->parvh.h[i][toklen[i + 4]] = '\0';
        }
        r->kind = ARVA_OK;
    }
}

/* ------------------------------------------------------------------ assembler ------ */

static arva_event *enqueue(arva_decoder *dec)
{
    arva_event *ev = &dec->queue[(dec->qhead + dec->qlen) % 3];
    dec->qlen++;
    return ev;
}

static void emit_epoch(arva_decoder *dec)
{
    arva_epoch *ep = &dec->ep[dec->cur];
    arva_event *ev;
    unsigned k;
    uint8_t complete = (uint8_t)!dec->tainted;
    for (k = 0; k < ep->n; k++) {
        if (!ep->present[k]) {
            complete = 0;
        }
    }
    ep->complete = complete;
    if (complete) {
        dec->stats.epochs_complete++;
    } else {
        dec->stats.epochs_incomplete++;
    }
    ev = enqueue(dec);
    ev->type = ARVA_EV_EPOCH;
    ev->offset = 0;
    ev->length = 0;
    ev->kind = ARVA_OK;
    ev->epoch = ep;
    dec->cur ^= 1U;
    dec->pending = 0;
    dec->holding = 0;
}

static void start_epoch(arva_decoder *dec, const arva_parva *p)
{
    arva_epoch *ep = &dec->ep[dec->cur];
    unsigned k;
    uint16_t gap = 0;
    if (dec->have_last_seq && p->seq != dec->last_seq) {
        gap = (uint16_t)(((uint32_t)p->seq - (uint32_t)dec->last_seq - 1U) & 0xFFFFU);
        if (gap != 0) {
            dec->stats.seq_gaps++;
            dec->stats.seqs_missing += gap;
        }
        if (p->seq < dec->last_seq) {
            dec->stats.seq_wraps++;
        }
    }
    dec->have_last_seq = 1;
    dec->last_seq = p->seq;
    ep->seq = p->seq;
    ep->n = p->n;
    ep->complete = 0;
    ep->gap = gap;
    ep->has_fields = 0;
    for (k = 0; k < p->n; k++) {
        ep->present[k] = 0;
        ep->field_present[k] = 0;
    }
    dec->pending = 1;
    dec->holding = 0;
    dec->tainted = 0;
}

static void slot_done(arva_decoder *dec, const arva_parva *p)
{
    arva_epoch *ep = &dec->ep[dec->cur];
    ep->present[p->k - 1] = 1;
    ep->slot[p->k - 1] = p->slot;
    dec->last_k = p->k;
    if (p->k == ep->n) {
        if (dec->expect_fields) {
            dec->holding = 1;
        } else {
            emit_epoch(dec);
        }
    }
}

static void queue_sentence(arva_decoder *dec, const parse_result *r, uint32_t offset)
{
    arva_event *ev = enqueue(dec);
    ev->offset = offset;
    ev->length = 0;
    ev->kind = ARVA_OK;
    ev->epoch = 0;
    if (r->is_parvh) {
        ev->type = ARVA_EV_PARVH;
        ev->s.parvh = r->parvh;
    } else {
        ev->type = ARVA_EV_PARVA;
        ev->s.parva = r->parva;
    }
}

static void on_parva(arva_decoder *dec, const parse_result *r, uint32_t offset)
{
    const arva_parva *p = &r->parva;
    if (dec->pending) {
        const arva_epoch *ep = &dec->ep[dec->cur];
        if (!dec->holding && p->seq == ep->seq && p->n == ep->n && p->k > dec->last_k) {
            queue_sentence(dec, r, offset);
            slot_done(dec, p);
            return;
        }
        emit_epoch(dec);
    }
    queue_sentence(dec, r, offset);
    start_epoch(dec, p);
    slot_done(dec, p);
}

static void on_parvh(arva_decoder *dec, const parse_result *r, uint32_t offset)
{
    const arva_parvh *h = &r->parvh;
    arva_epoch *ep = &dec->ep[dec->cur];
    int attach = 0;
    dec->expect_fields = 1;
    if (dec->pending && h->seq == ep->seq && h->k <= ep->n && ep->present[h->k - 1] && ep->slot[h->k - 1].id == h->id &&
        !ep->field_present[h->k - 1]) {
        attach = 1;
    }
    if (attach) {
        ep->field_present[h->k - 1] = 1;
        ep->has_fields = 1;
#if ARVA_WITH_FIELDS
        {
            unsigned i, j;
            for (i = 0; i < 3; i++) {
                for (j = 0; j <= ARVA_FIELD_TEXT_MAX; j++) {
                    ep->field[h->k - 1][i][j] = h->h[i][j];
                    if (h->h[i][j] == '\0') {
                        break;
                    }
                }
            }
        }
#endif
        queue_sentence(dec, r, offset);
        if (dec->holding) {
            emit_epoch(dec);
        }
        return;
    }
    dec->stats.fields_orphaned++;
    if (dec->holding) {
        emit_epoch(dec);
    }
    queue_sentence(dec, r, offset);
}

static void on_error(arva_decoder *dec, arva_error_kind kind, uint32_t offset, unsigned length)
{
    arva_event *ev;
    dec->stats.errors[kind]++;
    if (dec->holding) {
        emit_epoch(dec);
    } else if (dec->pending) {
        dec->tainted = 1;
    }
    ev = enqueue(dec);
    ev->type = ARVA_EV_ERROR;
    ev->offset = offset;
    ev->length = (uint16_t)length;
    ev->kind = kind;
    ev->epoch = 0;
}

/* ------------------------------------------------------------------ framing -------- */

static void complete_line(arva_decoder *dec)
{
    parse_result r;
    parse_line(dec->line, dec->len, (long)dec->max_d_cm, &r);
    if (r.kind != ARVA_OK) {
        on_error(dec, r.kind, dec->start, dec->len);
        return;
    }
    dec->stats.sentences_ok++;
    if (r.is_parvh) {
        on_parvh(dec, &r, dec->start);
    } else {
        on_parva(dec, &r, dec->start);
    }
}

static void push_byte(arva_decoder *dec, uint8_t b)
{
    uint32_t off = dec->offset++;
    dec->stats.bytes++;
    if (dec->len == 0) {
        if (b == '$') {
            dec->line[0] = b;
            dec->len = 1;
            dec->start = off;
        } else {
            dec->stats.garbage_bytes++;
        }
        return;
    }
    if (b == '$') {
        on_error(dec, ARVA_TRUNCATED, dec->start, dec->len);
        dec->line[0] = b;
        dec->len = 1;
        dec->start = off;
        return;
    }
    if (b == '\n') {
        dec->line[dec->len++] = b;
        complete_line(dec);
        dec->len = 0;
        return;
    }
    if ((b < 0x20 || b > 0x7E) && b != '\r') {
        on_error(dec, ARVA_NON_ASCII, dec->start, (unsigned)dec->len + 1U);
        dec->len = 0;
        return;
    }
    if (dec->len + 1 >= ARVA_MAX_SENTENCE) {
        on_error(dec, ARVA_TOO_LONG, dec->start, ARVA_MAX_SENTENCE);
        dec->len = 0;
        return;
    }
    dec->line[dec->len++] = b;
}

/* ------------------------------------------------------------------ public --------- */

void arva_decoder_init(arva_decoder *dec, int expect_fields)
{
    unsigned char *p = (unsigned char *)dec;
    size_t i;
    for (i = 0; i < sizeof *dec; i++) {
        p[i] = 0;
    }
    dec->expect_fields = (uint8_t)(expect_fields != 0);
    dec->max_d_cm = ARVA_MAX_D_CM;
}

int arva_decoder_set_max_range(arva_decoder *dec, long max_d_cm)
{
    if (max_d_cm < 0 || max_d_cm > ARVA_MAX_D_CM) {
        return -1;
    }
    dec->max_d_cm = (int32_t)max_d_cm;
    return 0;
}

/* A byte that simply extends an open sentence: printable ASCII except '$', or CR. */
static int ordinary(uint8_t b)
{
    return (b >= 0x20 && b <= 0x7E && b != '$') || b == '\r';
}

int arva_decoder_next(arva_decoder *dec, const uint8_t **data, size_t *len, arva_event *ev)
{
    if (dec->qlen == 0 && data != 0 && *data != 0 && len != 0) {
        const uint8_t *p = *data;
        const uint8_t *end = p + *len;
        /* Same machine as push_byte(), with the two common runs (garbage outside a
         * sentence, ordinary bytes inside one) handled in tight loops. */
        while (p < end && dec->qlen == 0) {
            const uint8_t *q = p;
            uint32_t run;
            if (dec->len == 0) {
                while (q < end && *q != '$') {
                    q++;
                }
                run = (uint32_t)(q - p);
                dec->stats.garbage_bytes += run;
            } else {
                uint8_t n = dec->len;
                unsigned room = (unsigned)(ARVA_MAX_SENTENCE - 1) - n;
                while (q < end && room > 0 && ordinary(*q)) {
                    dec->line[n++] = *q++;
                    room--;
                }
                dec->len = n;
                run = (uint32_t)(q - p);
            }
            dec->offset += run;
            dec->stats.bytes += run;
            p = q;
            if (p < end) {
                push_byte(dec, *p++);
            }
        }
        *data = p;
        *len = (size_t)(end - p);
    }
    if (dec->qlen == 0) {
        return 0;
    }
    *ev = dec->queue[dec->qhead];
    dec->qhead = (uint8_t)((dec->qhead + 1U) % 3U);
    dec->qlen--;
    return 1;
}

int arva_decoder_flush(arva_decoder *dec)
{
    if (dec->qlen != 0) {
        return -1;
    }
    if (dec->len != 0) {
        on_error(dec, ARVA_TRUNCATED, dec->start, dec->len);
        dec->len = 0;
    }
    if (dec->pending) {
        emit_epoch(dec);
    }
    return 0;
}

int arva_decoder_idle(arva_decoder *dec)
{
    if (dec->qlen != 0) {
        return -1;
    }
    if (dec->holding) {
        emit_epoch(dec);
    }
    return 0;
}

const char *arva_error_name(arva_error_kind kind)
{
    switch (kind) {
    case ARVA_OK:
        return "OK";
    case ARVA_BAD_CHECKSUM:
        return "BAD_CHECKSUM";
    case ARVA_TOO_LONG:
        return "TOO_LONG";
    case ARVA_NON_ASCII:
        return "NON_ASCII";
    case ARVA_MALFORMED:
        return "MALFORMED";
    case ARVA_OUT_OF_RANGE:
        return "OUT_OF_RANGE";
    case ARVA_UNKNOWN_SENTENCE:
        return "UNKNOWN_SENTENCE";
    case ARVA_TRUNCATED:
        return "TRUNCATED";
    }
    return "?";
}

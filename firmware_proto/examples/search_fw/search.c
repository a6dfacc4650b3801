/*
 * search.c - example firmware: the search logic of a drone that carries an ARVA receiver,
 * the same rules as docs/examples/search_dut.py (the Python reference device under test).
 *
 * Reads $PARVA sentences from UART0 with the project's C codec (firmware_proto/c,
 * unchanged), keeps a search state machine and writes one line per epoch on UART1, the
 * reference's JSON with the decoder's byte count added:
 *     {"seq": 12, "state": "coarse", "target": 1, "d": 1905, "bytes": 420}
 * States: no_signal (no target), coarse (target farther than 10 m), fine (within 10 m),
 * located (within 3 m). The first transmitter heard (the nearest, then the lowest id)
 * becomes the target and stays it while it is heard, even when a closer one appears; after
 * LOST_AFTER epochs without it the search starts again. An epoch is evaluated when its last
 * slot (k = n) arrives and its first slot (k = 1) was seen with the same seq, as the
 * reference does. A pulled cable is silence on the UART: nothing is evaluated meanwhile and
 * the state is kept. No timers: every decision follows from the bytes received, so the
 * decisions do not depend on how fast QEMU runs the core.
 */
#include "arva_codec.h"
#include "board.h"

#define FINE_CM 1000
#define LOCATED_CM 300
#define LOST_AFTER 3
#define NO_TARGET (-1L)

static arva_decoder dec;

/* --- output on UART1 ----------------------------------------------------------------- */

static void put_str(const char *s)
{
    while (*s != '\0') {
        uart_putc(UART1, *s++);
    }
}

static void put_int(long v)
{
    char buf[12];
    int i = 0;
    unsigned long u = (v < 0) ? (unsigned long)(-v) : (unsigned long)v;
    if (v < 0) {
        uart_putc(UART1, '-');
    }
    do {
        buf[i++] = (char)('0' + (u % 10u));
        u /= 10u;
    } while (u != 0u);
    while (i > 0) {
        uart_putc(UART1, buf[--i]);
    }
}

/* --- the search state machine -------------------------------------------------------- */

static long target = NO_TARGET;
static long target_d = -1;
static int missed;

static const char *state_name(void)
{
    if (target == NO_TARGET) {
        return "no_signal";
    }
    if (target_d <= LOCATED_CM) {
        return "located";
    }
    return target_d <= FINE_CM ? "fine" : "coarse";
}

/* One epoch's slots (count of them), as received. */
static void search_epoch(const arva_slot *slots, unsigned count)
{
    unsigned i;
    int found = 0;
    long best = NO_TARGET;
    long best_d = -1;
    if (target != NO_TARGET) {
        for (i = 0; i < count; i++) {
            if (slots[i].id == target && slots[i].d >= 0) {
                found = 1;
                target_d = slots[i].d;
            }
        }
        if (found) {
            missed = 0;
        } else if (++missed >= LOST_AFTER) {
            target = NO_TARGET;
            target_d = -1;
        }
    }
    if (target == NO_TARGET) {
        for (i = 0; i < count; i++) {
            const arva_slot *s = &slots[i];
            if (s->id < 0 || s->d < 0) {
                continue;
            }
            if (best == NO_TARGET || s->d < best_d || (s->d == best_d && s->id < best)) {
                best = s->id;
                best_d = s->d;
            }
        }
        if (best != NO_TARGET) {
            target = best;
            target_d = best_d;
            missed = 0;
        }
    }
}

static void report(uint16_t seq)
{
    put_str("{\"seq\": ");
    put_int(seq);
    put_str(", \"state\": \"");
    put_str(state_name());
    put_str("\", \"target\": ");
    if (target == NO_TARGET) {
        put_str("null");
    } else {
        put_int(target);
    }
    put_str(", \"d\": ");
    put_int(target_d);
    put_str(", \"bytes\": ");
    put_int((long)dec.stats.bytes);
    put_str("}\n");
}

/* --- epochs from single sentences, as the reference assembles them -------------------- */

static arva_slot slots[ARVA_MAX_CHANNELS];
static unsigned n_slots;
static int have_seq;
static uint16_t cur_seq;

static void on_parva(const arva_parva *p)
{
    if (p->k == 1) {
        n_slots = 0;
        cur_seq = p->seq;
        have_seq = 1;
    }
    if (!have_seq || p->seq != cur_seq) {
        return; /* a slot of an epoch whose start we missed */
    }
    if (n_slots < ARVA_MAX_CHANNELS) {
        slots[n_slots++] = p->slot;
    }
    if (p->k == p->n) {
        search_epoch(slots, n_slots);
        report(cur_seq);
    }
}

int main(void)
{
    arva_event ev;
    uart_init(UART0);
    uart_init(UART1);
    arva_decoder_init(&dec, 0);
    put_str("{\"event\": \"boot\", \"decoder_bytes\": ");
    put_int((long)sizeof dec);
    put_str("}\n");
    for (;;) {
        int c = uart_getc(UART0);
        if (c < 0) {
            continue;
        }
        uint8_t byte = (uint8_t)c;
        const uint8_t *p = &byte;
        size_t n = 1;
        while (arva_decoder_next(&dec, &p, &n, &ev)) {
            if (ev.type == ARVA_EV_PARVA) {
                on_parva(&ev.s.parva);
            }
        }
    }
}

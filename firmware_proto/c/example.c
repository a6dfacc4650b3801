/*
 * example.c - how firmware uses the codec (docs/protocol.md walks through it).
 * Transmit side: encode an epoch into a UART buffer. Receive side: feed whatever bytes
 * arrived and handle the events. No malloc, no stdio, no floating point.
 * Built and run by tests/firmware_proto/test_c_codec.py; exit status 0 when the round trip works.
 */
#include "arva_codec.h"

static arva_decoder rx; /* ~23 KB with the defaults: keep it static, not on the stack */

/* What the application does with decoded epochs; here: remember the last one. */
static uint16_t last_seq;
static uint8_t last_complete;
static int32_t last_d1;

static void on_event(const arva_event *ev)
{
    switch (ev->type) {
    case ARVA_EV_EPOCH:
        last_seq = ev->epoch->seq;
        last_complete = ev->epoch->complete;
        last_d1 = ev->epoch->present[0] ? ev->epoch->slot[0].d : -1;
        break;
    case ARVA_EV_ERROR: /* ev->kind, ev->offset, ev->length: count or log it */
    case ARVA_EV_PARVA: /* single sentences, if the application wants them */
    case ARVA_EV_PARVH:
    case ARVA_EV_NONE:
        break;
    }
}

/* Call from the main loop with the bytes the UART driver collected. */
static void uart_received(const uint8_t *bytes, size_t n)
{
    arva_event ev;
    while (arva_decoder_next(&rx, &bytes, &n, &ev)) {
        on_event(&ev);
    }
}

/* Call when the line has been quiet for ~100 ms (releases an epoch held for $PARVH). */
static void uart_idle(void)
{
    arva_event ev;
    if (arva_decoder_idle(&rx) == 0) {
        while (arva_decoder_next(&rx, 0, 0, &ev)) {
            on_event(&ev);
        }
    }
}

int main(void)
{
    /* Transmit: epoch 41 with two slots, the second empty. */
    arva_slot slots[2];
    char tx[2 * ARVA_MAX_SENTENCE];
    size_t len;
    slots[0].id = 1;
    slots[0].d = 1905;
    slots[0].delta = 21;
    slots[1].id = -1;
    slots[1].d = -1;
    slots[1].delta = -1;
    len = arva_encode_epoch(tx, sizeof tx, 41, slots, 2);
    if (len == 0) {
        return 1;
    }

    /* Receive it back, split in two reads as a UART would deliver it, after some noise. */
    arva_decoder_init(&rx, 0);
    uart_received((const uint8_t *)"\xff\x00noise", 7);
    uart_received((const uint8_t *)tx, 10);
    uart_received((const uint8_t *)tx + 10, len - 10);
    uart_idle();
    if (last_seq != 41 || !last_complete || last_d1 != 1905) {
        return 2;
    }
    if (rx.stats.garbage_bytes != 7 || rx.stats.sentences_ok != 2 || rx.stats.epochs_complete != 1) {
        return 3;
    }
    return 0;
}

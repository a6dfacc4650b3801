/*
 * board.h - the two CMSDK APB UARTs of QEMU's mps2-an385 (ARM MPS2 FPGA image AN385,
 * Cortex-M3, 25 MHz). Register layout from ARM's "Cortex-M System Design Kit" (DDI 0479):
 *   DATA 0x00, STATE 0x04 (bit 0 TX buffer full, bit 1 RX buffer full),
 *   CTRL 0x08 (bit 0 TX enable, bit 1 RX enable), INTSTATUS 0x0C, BAUDDIV 0x10.
 * Memory map used by link.ld: code in ZBT SSRAM1 at 0x00000000, data and stack in
 * SSRAM2 at 0x20000000. To port to another board, replace this file and link.ld.
 */
#ifndef BOARD_H
#define BOARD_H

#include <stdint.h>

#define UART0_BASE 0x40004000u /* the receiver's stream: $PARVA in */
#define UART1_BASE 0x40005000u /* the decisions: one line out per epoch */
#define SYSTEM_CLOCK_HZ 25000000u
#define BAUD 115200u

typedef struct {
    volatile uint32_t data;
    volatile uint32_t state;
    volatile uint32_t ctrl;
    volatile uint32_t intstatus;
    volatile uint32_t bauddiv;
} cmsdk_uart;

#define UART0 ((cmsdk_uart *)UART0_BASE)
#define UART1 ((cmsdk_uart *)UART1_BASE)
#define UART_STATE_TX_FULL 1u
#define UART_STATE_RX_FULL 2u
#define UART_CTRL_TX_EN 1u
#define UART_CTRL_RX_EN 2u

static inline void uart_init(cmsdk_uart *u)
{
    u->bauddiv = SYSTEM_CLOCK_HZ / BAUD; /* 217; QEMU refuses a divisor below 16 */
    /* Both directions: with RX off QEMU never delivers input, with TX off it drops output. */
    u->ctrl = UART_CTRL_TX_EN | UART_CTRL_RX_EN;
    (void)u->data; /* one read right away makes QEMU poll the host side at once (else ~1 s) */
}

static inline int uart_getc(cmsdk_uart *u)
{
    if ((u->state & UART_STATE_RX_FULL) == 0u) {
        return -1;
    }
    return (int)(u->data & 0xFFu);
}

static inline void uart_putc(cmsdk_uart *u, char c)
{
    while (u->state & UART_STATE_TX_FULL) {
    }
    u->data = (uint32_t)(unsigned char)c;
}

#endif /* BOARD_H */

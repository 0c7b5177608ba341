/*
 * The robot's wiring for the simulator harnesses: include/board.h's names (ENC_LEFT_A_BIT,
 * MOTOR_BRAKE_PORT, MOTOR_R_OCR, CYCLES_TCCRB, ...) with avr_regs.h's register names under
 * them, so that a register name expands to its data-space address (MOTOR_BRAKE_PORT -> PORTH
 * -> 0x102) and a bit name to its bit number. The harnesses use those names; this file adds
 * only what board.h cannot say: simavr names ports by letter and USARTs by digit (each checked
 * against board.h at compile time), and which vectors are the encoders'.
 * Include after every other header (avr_regs.h's macros are short upper-case names).
 */
#ifndef SIM_COMMON_BOARD_SIM_H
#define SIM_COMMON_BOARD_SIM_H

#include "avr_regs.h"
#include "board.h"

#ifdef __cplusplus
#define SIM_STATIC_ASSERT static_assert
#else
#define SIM_STATIC_ASSERT _Static_assert
#endif

/* simavr's name of ENC_PORT (AVR_IOCTL_IOPORT_GETIRQ) */
#define SIM_ENC_PORT_LETTER 'D'
SIM_STATIC_ASSERT(ENC_PORT == PORTD && ENC_PIN == PIND, "SIM_ENC_PORT_LETTER must name board.h's ENC_PORT");

/* simavr's name of the XBee USART (AVR_IOCTL_UART_GETIRQ) */
#define SIM_XBEE_UART_DIGIT '2'
SIM_STATIC_ASSERT(XBEE_UDR == UDR2, "SIM_XBEE_UART_DIGIT must name board.h's XBee USART");

/* the four encoder vectors of board.h (INTn with n = the pin's bit on ENC_PORT) */
#define SIM_IS_ENC_VECTOR(v) \
    ((v) == ENC_LEFT_A_VECT || (v) == ENC_LEFT_B_VECT || (v) == ENC_RIGHT_A_VECT || (v) == ENC_RIGHT_B_VECT)

#endif /* SIM_COMMON_BOARD_SIM_H */

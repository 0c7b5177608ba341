/*
 * The robot's wiring as the simulator harnesses see it: which port bit carries which signal
 * (include/board.h's wiring, docs/firmware.md "Pins"), as avr_regs.h data addresses and bits.
 * Include after avr_regs.h.
 */
#ifndef SIM_COMMON_BOARD_SIM_H
#define SIM_COMMON_BOARD_SIM_H

#include "avr_regs.h"
#include "board.h"

/* encoders: left A/B = PD0/PD1 (INT0/INT1), right A/B = PD2/PD3 (INT2/INT3) */
#define SIM_ENC_PORT 'D'
#define SIM_ENC_LEFT_A_BIT PD0
#define SIM_ENC_RIGHT_A_BIT PD2 /* B is the next bit of each wheel */
#define SIM_ENC_PINS_MASK ((1u << PD0) | (1u << PD1) | (1u << PD2) | (1u << PD3))
#define SIM_ENC_FIRST_VECTOR INT0_vect
#define SIM_ENC_LAST_VECTOR INT3_vect
#define SIM_ENC_INT_MASK ((1u << INT0) | (1u << INT1) | (1u << INT2) | (1u << INT3)) /* in EIMSK */

/* motor shield: channel A -> right wheel, channel B -> left wheel */
#define SIM_BRAKE_RIGHT_BIT PH6 /* PORTH, pin 9 */
#define SIM_BRAKE_LEFT_BIT PH5  /* PORTH, pin 8 */
#define SIM_BRAKE_BOTH_MASK ((1u << SIM_BRAKE_RIGHT_BIT) | (1u << SIM_BRAKE_LEFT_BIT))
#define SIM_DIR_RIGHT_BIT PB6 /* PORTB, pin 12 */
#define SIM_DIR_LEFT_BIT PB7  /* PORTB, pin 13 */
/* PWM: right = OC3C on PE5 (Timer3, TOP = ICR3), left = OC1A on PB5 (Timer1, TOP = ICR1) */
#define SIM_PWM_RIGHT_BIT PE5
#define SIM_PWM_LEFT_BIT PB5

/* XBee: USART2 */
#define SIM_XBEE_UART '2'

#endif /* SIM_COMMON_BOARD_SIM_H */

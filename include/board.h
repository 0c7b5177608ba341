// Board wiring and clock of the robot: Arduino Mega 2560 + Arduino Motor Shield R3.
// Every port, pin bit, timer, interrupt vector and general-purpose I/O register the firmware
// uses is named here once; src/ uses these names, not the register names they stand for, so
// moving a wire or a timer is a change to this file only.
//
// Plain #defines only: this header is also included by the assembler (src/encoder_isr.S) and
// by host programs (the simulators), which use only the plain numbers. A name that stands for a
// register is expanded where it is used, after <avr/io.h>.
//
//   encoders  left  A = pin 21 = PD0/INT0, B = pin 20 = PD1/INT1
//             right A = pin 19 = PD2/INT2, B = pin 18 = PD3/INT3
//   shield    channel A (PWM pin 3 = OC3C/PE5, DIR 12 = PB6, BRAKE 9 = PH6, sense A0)  -> RIGHT wheel
//             channel B (PWM pin 11 = OC1A/PB5, DIR 13 = PB7, BRAKE 8 = PH5, sense A1) -> LEFT wheel
//             (A0 = right matches protocol/protocol.json's telemetry.current_r)
//   XBee      USART2 (TX2 pin 16 = PH1, RX2 pin 17 = PH0)
//   timers    Timer3, Timer1: motor PWM; Timer4: 1 kHz scheduler tick; Timer5: cycle clock
//   debug     USART0 (pins 0/1, the USB bridge): Unity output in the embedded tests
#ifndef FW_BOARD_H
#define FW_BOARD_H

#ifndef F_CPU
#define F_CPU 16000000UL
#endif

// ---- Encoders --------------------------------------------------------------------------
// Forward rotation of a wheel (robot moves forward) produces, per wheel, the Gray sequence
//   A leads B:  (B,A) = 00 -> 01 -> 11 -> 10 -> 00     when ENC_<wheel>_REVERSED == 0
//   B leads A:  (B,A) = 00 -> 10 -> 11 -> 01 -> 00     when ENC_<wheel>_REVERSED == 1
// The left motor is mounted mirrored, so on the robot its channels run B-before-A when driving
// forward. Flip these (compile time, no run-time cost) if the wiring differs.
#ifndef ENC_LEFT_REVERSED
#define ENC_LEFT_REVERSED 1
#endif
#ifndef ENC_RIGHT_REVERSED
#define ENC_RIGHT_REVERSED 0
#endif
// Encoder counts per wheel revolution: the model's (slip::kEncoderPpr) generated constant from
// params/params.json, so the firmware and the model cannot disagree.
#include "../lib/slipmodel/src/slipmodel/params_table.h"  // by path: C harnesses include board.h too
#define ENC_COUNTS_PER_REV SLIP_ENCODER_COUNTS_PER_REV
// All four channels on one port, A in the lower bit of each wheel's pair: the ISRs read a
// wheel's state with one IN and mask it, and their transition table needs the left pair in
// bits 0-1 and the right pair in bits 2-3 (src/encoder_isr.S checks this).
#define ENC_PORT PORTD
#define ENC_DDR DDRD
#define ENC_PIN PIND
#define ENC_LEFT_A_BIT PD0
#define ENC_LEFT_B_BIT PD1
#define ENC_RIGHT_A_BIT PD2
#define ENC_RIGHT_B_BIT PD3
#define ENC_LEFT_MASK ((1 << ENC_LEFT_A_BIT) | (1 << ENC_LEFT_B_BIT))
#define ENC_RIGHT_MASK ((1 << ENC_RIGHT_A_BIT) | (1 << ENC_RIGHT_B_BIT))
#define ENC_MASK (ENC_LEFT_MASK | ENC_RIGHT_MASK)
// External interrupts INT0..INT3 (EIMSK/EIFR bits 0..3), any logical change (ISCn = 01).
#define ENC_LEFT_A_VECT INT0_vect
#define ENC_LEFT_B_VECT INT1_vect
#define ENC_RIGHT_A_VECT INT2_vect
#define ENC_RIGHT_B_VECT INT3_vect
#define ENC_INT_MASK ((1 << INT0) | (1 << INT1) | (1 << INT2) | (1 << INT3))
#define ENC_EICRA_ANY_CHANGE ((1 << ISC00) | (1 << ISC10) | (1 << ISC20) | (1 << ISC30))
// ISR state in general-purpose I/O registers (1-cycle IN/OUT; no other code touches them).
#define ENC_PREV_L_GPIOR GPIOR0   // left wheel's previous pin state (ENC_PIN & ENC_LEFT_MASK)
#define ENC_PREV_R_GPIOR GPIOR1   // right wheel's previous pin state (ENC_PIN & ENC_RIGHT_MASK)
#define ENC_SREG_GPIOR GPIOR2     // SREG stash (the encoder ISRs never nest)

// ---- Motor shield ----------------------------------------------------------------------
// Direction pin level that drives a wheel forward (the left motor is mirrored).
#ifndef MOTOR_LEFT_DIR_FORWARD_LEVEL
#define MOTOR_LEFT_DIR_FORWARD_LEVEL 0
#endif
#ifndef MOTOR_RIGHT_DIR_FORWARD_LEVEL
#define MOTOR_RIGHT_DIR_FORWARD_LEVEL 1
#endif
// Fast PWM (WGM 14, TOP = ICRn), prescaler 1: f = F_CPU / (TOP + 1) = 20 kHz, 800 steps.
#define MOTOR_PWM_TOP 799u
// Right wheel (channel A): PWM pin 3 = PE5 = OC3C of Timer3.
#define MOTOR_R_PWM_PORT PORTE
#define MOTOR_R_PWM_DDR DDRE
#define MOTOR_R_PWM_BIT PE5
#define MOTOR_R_TCCRA TCCR3A
#define MOTOR_R_TCCRB TCCR3B
#define MOTOR_R_ICR ICR3
#define MOTOR_R_TCNT TCNT3
#define MOTOR_R_OCR OCR3C
#define MOTOR_R_COM1 COM3C1   // COM bits of OC3C: 10 = non-inverting, 00 = disconnected
#define MOTOR_R_COM0 COM3C0
#define MOTOR_R_TCCRA_MODE (1 << WGM31)                                 // WGM 14, low bits
#define MOTOR_R_TCCRB_RUN ((1 << WGM33) | (1 << WGM32) | (1 << CS30))  // WGM 14, clk/1
// Left wheel (channel B): PWM pin 11 = PB5 = OC1A of Timer1.
#define MOTOR_L_PWM_PORT PORTB
#define MOTOR_L_PWM_DDR DDRB
#define MOTOR_L_PWM_BIT PB5
#define MOTOR_L_TCCRA TCCR1A
#define MOTOR_L_TCCRB TCCR1B
#define MOTOR_L_ICR ICR1
#define MOTOR_L_TCNT TCNT1
#define MOTOR_L_OCR OCR1A
#define MOTOR_L_COM1 COM1A1
#define MOTOR_L_COM0 COM1A0
#define MOTOR_L_TCCRA_MODE (1 << WGM11)
#define MOTOR_L_TCCRB_RUN ((1 << WGM13) | (1 << WGM12) | (1 << CS10))
// Direction: pin 12 = PB6 (right), pin 13 = PB7 (left), one port.
#define MOTOR_DIR_PORT PORTB
#define MOTOR_DIR_DDR DDRB
#define MOTOR_R_DIR_BIT PB6
#define MOTOR_L_DIR_BIT PB7
#define MOTOR_DIR_MASK ((1 << MOTOR_R_DIR_BIT) | (1 << MOTOR_L_DIR_BIT))
// Brake (high = brake): pin 9 = PH6 (right), pin 8 = PH5 (left), one port.
#define MOTOR_BRAKE_PORT PORTH
#define MOTOR_BRAKE_DDR DDRH
#define MOTOR_R_BRAKE_BIT PH6
#define MOTOR_L_BRAKE_BIT PH5
#define MOTOR_BRAKE_MASK ((1 << MOTOR_R_BRAKE_BIT) | (1 << MOTOR_L_BRAKE_BIT))
// Current sense: A0 = ADC0 (right), A1 = ADC1 (left); MUX values, digital input buffers off.
#define MOTOR_R_SENSE_MUX 0
#define MOTOR_L_SENSE_MUX 1
#define MOTOR_SENSE_DIDR DIDR0
#define MOTOR_SENSE_DIDR_MASK ((1 << ADC0D) | (1 << ADC1D))

// ---- Scheduler tick: Timer4, CTC (WGM 4, TOP = OCR4A), clk/64 -> 250 kHz, 1 kHz tick ------
#define SCHED_TICK_HZ 1000UL
#define SCHED_PRESCALER 64UL
#define SCHED_TOP ((F_CPU / SCHED_PRESCALER / SCHED_TICK_HZ) - 1)   // 249
#define SCHED_TCCRA TCCR4A
#define SCHED_TCCRB TCCR4B
#define SCHED_OCR OCR4A
#define SCHED_TCNT TCNT4
#define SCHED_TIFR TIFR4
#define SCHED_TIMSK TIMSK4
#define SCHED_OCF OCF4A
#define SCHED_OCIE OCIE4A
#define SCHED_TCCRB_RUN ((1 << WGM42) | (1 << CS41) | (1 << CS40))   // CTC, clk/64
#define SCHED_TICK_VECT TIMER4_COMPA_vect

// ---- Cycle clock: Timer5, normal mode, clk/1, extended by its overflow interrupt ----------
#define CYCLES_TCCRA TCCR5A
#define CYCLES_TCCRB TCCR5B
#define CYCLES_TCNT TCNT5
#define CYCLES_TIFR TIFR5
#define CYCLES_TIMSK TIMSK5
#define CYCLES_TOV TOV5
#define CYCLES_TOIE TOIE5
#define CYCLES_TCCRB_RUN (1 << CS50)
#define CYCLES_OVF_VECT TIMER5_OVF_vect

// ---- XBee: USART2 ----------------------------------------------------------------------
// 115200 baud with U2X: UBRR = 16 -> 117647 baud (+2.1 %), the usual Mega 2560 setting.
#define XBEE_BAUD 115200UL
#define XBEE_UBRR 16u
#define XBEE_U2X 1
#define XBEE_UCSRA UCSR2A
#define XBEE_UCSRB UCSR2B
#define XBEE_UCSRC UCSR2C
#define XBEE_UBRRN UBRR2
#define XBEE_UDR UDR2
#define XBEE_U2X_BIT U2X2
#define XBEE_FE_BIT FE2
#define XBEE_DOR_BIT DOR2
#define XBEE_RXEN_BIT RXEN2
#define XBEE_TXEN_BIT TXEN2
#define XBEE_RXCIE_BIT RXCIE2
#define XBEE_UDRIE_BIT UDRIE2
#define XBEE_UCSRC_8N1 ((1 << UCSZ21) | (1 << UCSZ20))
#define XBEE_RX_VECT USART2_RX_vect
#define XBEE_UDRE_VECT USART2_UDRE_vect

#endif  // FW_BOARD_H

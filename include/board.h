// Board wiring and clock of the robot: Arduino Mega 2560 + Arduino Motor Shield R3.
// Plain #defines only: this header is also included by the assembler (src/encoder_isr.S).
//
// Wiring decisions (see docs/firmware.md, "Pins"):
//   encoders  left  A = pin 21 = PD0/INT0, B = pin 20 = PD1/INT1
//             right A = pin 19 = PD2/INT2, B = pin 18 = PD3/INT3
//   shield    channel A (PWM pin 3 = OC3C/PE5, DIR 12 = PB6, BRAKE 9 = PH6, sense A0)  -> RIGHT wheel
//             channel B (PWM pin 11 = OC1A/PB5, DIR 13 = PB7, BRAKE 8 = PH5, sense A1) -> LEFT wheel
//             (A0 = right matches protocol/protocol.json's telemetry.current_r)
//   XBee      USART2 (TX2 pin 16 = PH1, RX2 pin 17 = PH0)
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
#define ENC_COUNTS_PER_REV 1856

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

// ---- XBee ------------------------------------------------------------------------------
// 115200 baud with U2X: UBRR = 16 -> 117647 baud (+2.1 %), the usual Mega 2560 setting.
#define XBEE_BAUD 115200UL
#define XBEE_UBRR 16u
#define XBEE_U2X 1

#endif  // FW_BOARD_H

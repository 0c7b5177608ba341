// Arduino Motor Shield R3 driver: fast PWM at 20 kHz on OC3C (pin 3, channel A, right wheel)
// and OC1A (pin 11, channel B, left wheel), direction on 12/13, brake on 9/8, current sense
// on A0/A1 (ADC, interrupt-driven, one conversion pair per motor_sense_start()).
// Pins are made safe before main() in boot.cpp (.init3): PWM low, brake on.
#ifndef FW_MOTOR_H
#define FW_MOTOR_H

#include <stdint.h>

enum Wheel : uint8_t { kRight = 0, kLeft = 1 };

void motor_init();           // timers, ADC; motors stay off (duty 0, brake on)
// Signed duty in Q15 (-32768..32767 = -1..1), positive = wheel forward. Releases the brake.
void motor_set_q15(Wheel w, int16_t duty_q15);
// Both duties, then a ramp: every millisecond (motor_ramp_tick() from the 1 kHz tick ISR) each
// duty grows by its slope (Q15 per ms), at most `steps` times. The next call, motor_set_q15() or
// the brake ends it. The controller's torque->PWM map asks for it (lib/control/README.md).
void motor_set_ramp_q15(int16_t duty_r, int16_t slope_r, int16_t duty_l, int16_t slope_l, uint8_t steps);
void motor_ramp_tick();
// Both motors: brake pins high and enable high (L298 both low-side on: terminals shorted).
void motor_brake();
bool motor_braking();
// Applied duty (Q15) as last set (0 while braking).
int16_t motor_duty_q15(Wheel w);
// Timer counts per PWM period the enable pin is high (0..MOTOR_PWM_TOP+1; the OCR register
// holds this minus one), for tests and the FIL simulator.
uint16_t motor_compare(Wheel w);

// Current sense: starts A0 then A1 conversions (ADC ISR, 104 us each; ignored while a pair
// converts), every 1 kHz tick; results are raw 10-bit counts of the last completed conversions.
void motor_sense_start();
uint16_t motor_sense_raw(Wheel w);

#endif  // FW_MOTOR_H

#include "motor.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#include "board.h"

// Pins, timers and ADC channels: include/board.h (MOTOR_R_* = channel A, MOTOR_L_* = channel B).
namespace {
int16_t g_duty[2];
bool g_braking = true;
int16_t g_slope[2];               // duty ramp (Q15 per ms), stepped by motor_ramp_tick()
volatile uint8_t g_ramp_left;     // ramp steps left (0: no ramp)
volatile uint16_t g_sense[2];
volatile uint8_t g_sense_ch = 2;   // channel converting: 0 = A0, 1 = A1, 2 = pair done (idle)

const uint16_t kTop = MOTOR_PWM_TOP;

// In fast PWM (non-inverting) the pin is high for OCR + 1 of the TOP + 1 counts of a period, and
// constantly high at OCR = TOP. So `high_counts` in 1..TOP+1 is written as OCR = high_counts - 1;
// high_counts == 0 disconnects OCnx and holds the pin low (OCR = 0 would still emit a one-count
// pulse per period).
void set_compare(Wheel w, uint16_t high_counts) {
    if (high_counts > kTop + 1u) high_counts = kTop + 1u;
    if (w == kRight) {
        if (high_counts == 0) {
            MOTOR_R_TCCRA &= static_cast<uint8_t>(~(_BV(MOTOR_R_COM1) | _BV(MOTOR_R_COM0)));
            MOTOR_R_PWM_PORT &= static_cast<uint8_t>(~_BV(MOTOR_R_PWM_BIT));
            MOTOR_R_OCR = 0;
        } else {
            MOTOR_R_OCR = high_counts - 1u;
            MOTOR_R_TCCRA |= _BV(MOTOR_R_COM1);
        }
    } else {
        if (high_counts == 0) {
            MOTOR_L_TCCRA &= static_cast<uint8_t>(~(_BV(MOTOR_L_COM1) | _BV(MOTOR_L_COM0)));
            MOTOR_L_PWM_PORT &= static_cast<uint8_t>(~_BV(MOTOR_L_PWM_BIT));
            MOTOR_L_OCR = 0;
        } else {
            MOTOR_L_OCR = high_counts - 1u;
            MOTOR_L_TCCRA |= _BV(MOTOR_L_COM1);
        }
    }
}

// A wheel's timer: fast PWM, WGM 14 (TOP = ICRn), clk/1 -> 16 MHz / 800 = 20 kHz, its output
// off until used. TOP and compare are written before the clock starts (TCCRnB last): simavr 1.6
// takes TOP from ICRn only when the mode is set, and on the hardware nothing runs half-configured.
inline __attribute__((always_inline)) void pwm_timer_init(volatile uint8_t& tccra, volatile uint8_t& tccrb,
                                                          volatile uint16_t& icr, volatile uint16_t& ocr,
                                                          volatile uint16_t& tcnt, uint8_t mode_a, uint8_t run_b) {
    tccrb = 0;
    tccra = mode_a;
    icr = kTop;
    ocr = 0;
    tcnt = 0;
    tccrb = run_b;
}

void set_dir(Wheel w, bool forward) {
    bool level = w == kRight ? (forward == (MOTOR_RIGHT_DIR_FORWARD_LEVEL != 0))
                             : (forward == (MOTOR_LEFT_DIR_FORWARD_LEVEL != 0));
    uint8_t bit = w == kRight ? _BV(MOTOR_R_DIR_BIT) : _BV(MOTOR_L_DIR_BIT);
    if (level) MOTOR_DIR_PORT |= bit;
    else MOTOR_DIR_PORT &= static_cast<uint8_t>(~bit);
}

void set_brake(bool on) {
    if (on) MOTOR_BRAKE_PORT |= MOTOR_BRAKE_MASK;
    else MOTOR_BRAKE_PORT &= static_cast<uint8_t>(~MOTOR_BRAKE_MASK);
}
}  // namespace

void motor_init() {
    // Safe levels first (boot.cpp already did this in .init3; repeated for clarity).
    set_brake(true);
    MOTOR_BRAKE_DDR |= MOTOR_BRAKE_MASK;
    MOTOR_L_PWM_PORT &= static_cast<uint8_t>(~_BV(MOTOR_L_PWM_BIT));
    MOTOR_L_PWM_DDR |= _BV(MOTOR_L_PWM_BIT);
    MOTOR_DIR_PORT &= static_cast<uint8_t>(~MOTOR_DIR_MASK);
    MOTOR_DIR_DDR |= MOTOR_DIR_MASK;
    MOTOR_R_PWM_PORT &= static_cast<uint8_t>(~_BV(MOTOR_R_PWM_BIT));
    MOTOR_R_PWM_DDR |= _BV(MOTOR_R_PWM_BIT);
    pwm_timer_init(MOTOR_R_TCCRA, MOTOR_R_TCCRB, MOTOR_R_ICR, MOTOR_R_OCR, MOTOR_R_TCNT,
                   MOTOR_R_TCCRA_MODE, MOTOR_R_TCCRB_RUN);
    pwm_timer_init(MOTOR_L_TCCRA, MOTOR_L_TCCRB, MOTOR_L_ICR, MOTOR_L_OCR, MOTOR_L_TCNT,
                   MOTOR_L_TCCRA_MODE, MOTOR_L_TCCRB_RUN);
    g_duty[0] = g_duty[1] = 0;
    g_braking = true;
    // ADC: AVcc reference, clk/128 = 125 kHz (13 cycles = 104 us per conversion), interrupt.
    ADMUX = _BV(REFS0);
    ADCSRB = 0;
    MOTOR_SENSE_DIDR = MOTOR_SENSE_DIDR_MASK;
    ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
}

void motor_set_q15(Wheel w, int16_t duty_q15) {
    bool fwd = duty_q15 >= 0;
    uint16_t mag = fwd ? static_cast<uint16_t>(duty_q15)
                       : (duty_q15 == -32768 ? 32768u : static_cast<uint16_t>(-duty_q15));
    // high counts per period: (TOP + 1) * |d| / 32768, rounded; 32767 -> 800 of 800 (rounded up),
    // -32768 -> 800 (100 %).
    uint16_t cmp = static_cast<uint16_t>((static_cast<uint32_t>(kTop + 1u) * mag + 16384u) >> 15);
    uint8_t sreg = SREG;
    cli();  // 16-bit OCR writes and COM bit RMW
    if (g_braking) {
        set_brake(false);
        g_braking = false;
        set_compare(w == kRight ? kLeft : kRight, 0);  // the other wheel: off until set
        g_duty[w == kRight ? 1 : 0] = 0;
    }
    set_dir(w, fwd);
    set_compare(w, cmp);
    SREG = sreg;
    g_duty[w] = duty_q15;
}

void motor_set_ramp_q15(int16_t duty_r, int16_t slope_r, int16_t duty_l, int16_t slope_l, uint8_t steps) {
    g_ramp_left = 0;  // the tick ISR leaves the duties alone while they change
    motor_set_q15(kRight, duty_r);
    motor_set_q15(kLeft, duty_l);
    if (slope_r == 0 && slope_l == 0) return;
    uint8_t sreg = SREG;
    cli();
    g_slope[0] = slope_r;
    g_slope[1] = slope_l;
    g_ramp_left = steps;
    SREG = sreg;
}

// From the 1 kHz tick ISR (interrupts enabled: it never runs inside motor_set_q15's cli region,
// and the main context clears g_ramp_left before it sets duties or brakes).
void motor_ramp_tick() {
    if (g_ramp_left == 0 || g_braking) return;
    g_ramp_left = g_ramp_left - 1;
    for (uint8_t w = 0; w < 2; ++w) {
        int32_t d = static_cast<int32_t>(g_duty[w]) + g_slope[w];
        if (d > 32767) d = 32767;
        if (d < -32767) d = -32767;
        motor_set_q15(static_cast<Wheel>(w), static_cast<int16_t>(d));
    }
}

void motor_brake() {
    g_ramp_left = 0;
    uint8_t sreg = SREG;
    cli();
    set_brake(true);
    set_compare(kRight, kTop + 1u);  // enable high: with BRAKE high the shield shorts the motor
    set_compare(kLeft, kTop + 1u);
    SREG = sreg;
    g_duty[0] = g_duty[1] = 0;
    g_braking = true;
}

bool motor_braking() { return g_braking; }
int16_t motor_duty_q15(Wheel w) { return g_duty[w]; }

uint16_t motor_compare(Wheel w) {  // counts per period the pin is high (0..TOP + 1)
    if (w == kRight) return (MOTOR_R_TCCRA & _BV(MOTOR_R_COM1)) ? static_cast<uint16_t>(MOTOR_R_OCR + 1u) : 0;
    return (MOTOR_L_TCCRA & _BV(MOTOR_L_COM1)) ? static_cast<uint16_t>(MOTOR_L_OCR + 1u) : 0;
}

// Called by the 1 kHz tick (an ISR that re-enables interrupts): while g_sense_ch is 2 no
// conversion runs, so no ADC interrupt can come between the test and the start.
void motor_sense_start() {
    if (g_sense_ch != 2) return;  // previous pair still converting
    g_sense_ch = 0;
    ADMUX = _BV(REFS0) | MOTOR_R_SENSE_MUX;
    ADCSRA |= _BV(ADSC);
}

uint16_t motor_sense_raw(Wheel w) {
    uint8_t sreg = SREG;
    cli();
    uint16_t v = g_sense[w == kRight ? 0 : 1];
    SREG = sreg;
    return v;
}

// NOBLOCK: encoder edges may interrupt it (ADIF is cleared on entry; the next conversion
// it starts takes 104 us, so it cannot re-enter itself).
ISR(ADC_vect, ISR_NOBLOCK) {
    uint16_t v = ADC;
    if (g_sense_ch == 0) {
        g_sense[0] = v;
        g_sense_ch = 1;
        ADMUX = _BV(REFS0) | MOTOR_L_SENSE_MUX;
        ADCSRA |= _BV(ADSC);
    } else {
        g_sense[1] = v;
        g_sense_ch = 2;
    }
}

// Current sense: the Motor Shield R3's sense outputs on A0 (right) and A1 (left), read by the
// firmware's own ADC code. At the sample instant of each conversion (sim/common: 1.5 ADC clocks
// after its start) the channel's input becomes |the plant's armature current| x the shield's
// volts per ampere, as a fraction of AVcc; both from protocol.json's current_sense (messages.h).
#include "fil.h"

#include <math.h>

#include <protocol/messages.h>

namespace fil {

void Fil::setup_sense() {
    avrsim_adc_sampler(&sim, [](void* p, int ch, avr_cycle_count_t when) { static_cast<Fil*>(p)->sense_sample(ch, when); },
                       this);
}

void Fil::sense_sample(int channel, avr_cycle_count_t when) {
    int w = channel == MOTOR_R_SENSE_MUX ? 0 : channel == MOTOR_L_SENSE_MUX ? 1 : -1;
    double i_a = w >= 0 ? plant.current_a(w) : 0.0;  // the step in progress: the current is constant in it
    double v = fabs(i_a) * proto::kCurrentSenseVoltsPerAmp;
    avrsim_adc_input(&sim, channel, v / proto::kCurrentSenseAdcVrefV);
    ++adc_samples;
    if (w >= 0 && fabs(i_a) > sense_max_a[w]) sense_max_a[w] = fabs(i_a);
    if (adc_f && w >= 0 && board_origin_set)
        fprintf(adc_f, "%.7f,%d,%.6f,%.5f\n", board_t(when), w, i_a, v);
}

}  // namespace fil

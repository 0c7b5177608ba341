// The parameter table's values as the native tests use them (params/params.json through the
// generated slipmodel/params_table.h): the controller's API takes float and int32_t.
#ifndef TEST_NATIVE_TABLE_H
#define TEST_NATIVE_TABLE_H

#include <stdint.h>

#include <slipmodel/params_table.h>

namespace tbl {
constexpr float kWheelR_m = static_cast<float>(slip::table::r);     // Table II.2 r
constexpr float kHalfTrack_m = static_cast<float>(slip::table::b);  // Table II.2 b (half of 2b)
constexpr int32_t kPpr = SLIP_ENCODER_COUNTS_PER_REV;              // encoder counts per turn
}  // namespace tbl

#endif  // TEST_NATIVE_TABLE_H

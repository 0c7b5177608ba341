// Shared by the native Unity suites: a double-precision comparison that fails on NaN.
// Unity's double assertions fail with "Double Precision Disabled" unless UNITY_INCLUDE_DOUBLE
// is set for the whole build (unity.c too), so the suites use these instead.
#ifndef TEST_NATIVE_EXPECT_NEAR_H
#define TEST_NATIVE_EXPECT_NEAR_H

#include <math.h>
#include <stdio.h>
#include <unity.h>

// EXPECT_NEAR(tol, expected, actual)
#define EXPECT_NEAR(tol, expected, actual)                                                \
  do {                                                                                    \
    const double e_ = (expected), a_ = (actual), t_ = (tol);                              \
    char m_[128];                                                                         \
    snprintf(m_, sizeof(m_), "expected %.12g +- %.3g, got %.12g", e_, t_, a_);            \
    TEST_ASSERT_MESSAGE(fabs(a_ - e_) <= t_, m_);                                         \
  } while (0)

// CHECK_NEAR(expected, actual, tol, what): the same with a label
#define CHECK_NEAR(expected, actual, tol, what)                                              \
  do {                                                                                       \
    const double e_ = (expected), a_ = (actual), t_ = (tol);                                 \
    if (!(fabs(e_ - a_) <= t_)) {                                                            \
      char m_[200];                                                                          \
      snprintf(m_, sizeof m_, "%s: expected %.9g got %.9g (tol %.3g)", what, e_, a_, t_);    \
      TEST_FAIL_MESSAGE(m_);                                                                 \
    }                                                                                        \
  } while (0)

#endif

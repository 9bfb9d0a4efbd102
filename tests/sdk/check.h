/* The C API tests' checks: CHECK counts a failure and prints the condition with this thread's
 * last error; EXPECT_ERROR checks a call's result code and message. Each test program includes
 * this once and returns non-zero when `failures` is. */
#ifndef PSTREAM_TESTS_SDK_CHECK_H
#define PSTREAM_TESTS_SDK_CHECK_H

#include <stdio.h>
#include <string.h>

#include <particlestream/particlestream.h>

static int failures = 0;

#define CHECK(cond)                                                                                             \
  do {                                                                                                          \
    if (!(cond)) {                                                                                              \
      fprintf(stderr, "%s:%d: failed: %s (last error: %s)\n", __FILE__, __LINE__, #cond, pstream_last_error()); \
      ++failures;                                                                                               \
    }                                                                                                           \
  } while (0)

/* The call returns `code` and leaves a message naming `fragment`. */
#define EXPECT_ERROR(call, code, fragment)                                                              \
  do {                                                                                                  \
    const pstream_result r_ = (call);                                                                   \
    CHECK(r_ == (code));                                                                                \
    CHECK(strstr(pstream_last_error(), (fragment)) != NULL);                                            \
    if (r_ != (code)) fprintf(stderr, "  got %s: %s\n", pstream_result_name(r_), pstream_last_error()); \
  } while (0)

#endif

/* The assertions of the C test drivers: CHECK(cond, fmt, ...) counts a failure and prints the
 * file, the line, the message and the last log line the FMU wrote (the driver's logger keeps it
 * in `last`). Included by one translation unit per test program. */
#ifndef UIOFMU_TEST_CHECK_H
#define UIOFMU_TEST_CHECK_H

#include <stdarg.h>
#include <stdio.h>

static int failures;
static char last[1024];

static void fail(const char *file, int line, const char *fmt, ...) {
    va_list ap;
    failures++;
    fprintf(stderr, "FAIL %s:%d: ", file, line);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fprintf(stderr, " (last log line: %s)\n", last[0] ? last : "none");
}
#define CHECK(cond, ...) do { if (!(cond)) fail(__FILE__, __LINE__, __VA_ARGS__); } while (0)

#endif

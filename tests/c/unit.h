/* Minimal C unit-test kit for libfap: CHECK* macros record failures with
 * file:line and keep going; UNIT_MAIN runs the listed test functions and
 * prints "N passed, N failed" (one check = one count). Exit 1 on failure. */
#ifndef LF_UNIT_H
#define LF_UNIT_H
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int unit_passed, unit_failed;
static const char *unit_current = "";

#define CHECK(cond) do { \
    if (cond) unit_passed++; \
    else { unit_failed++; fprintf(stderr, "%s:%d: %s: CHECK(%s) failed\n", \
           __FILE__, __LINE__, unit_current, #cond); } } while (0)

#define CHECK_EQ(a, b) do { \
    long long va_ = (long long)(a), vb_ = (long long)(b); \
    if (va_ == vb_) unit_passed++; \
    else { unit_failed++; fprintf(stderr, "%s:%d: %s: %s == %s failed: %lld != %lld\n", \
           __FILE__, __LINE__, unit_current, #a, #b, va_, vb_); } } while (0)

#define CHECK_MEM(a, b, n) do { \
    if (memcmp((a), (b), (n)) == 0) unit_passed++; \
    else { unit_failed++; fprintf(stderr, "%s:%d: %s: memory %s != %s (%zu bytes)\n", \
           __FILE__, __LINE__, unit_current, #a, #b, (size_t)(n)); } } while (0)

/* Stop the current test (a later check would only crash). The condition
 * is evaluated exactly once: REQUIRE(open(...) == 0) opens once. */
#define REQUIRE(cond) do { \
    int ok_ = !!(cond); \
    if (ok_) unit_passed++; \
    else { unit_failed++; fprintf(stderr, "%s:%d: %s: REQUIRE(%s) failed\n", \
           __FILE__, __LINE__, unit_current, #cond); return; } } while (0)

typedef struct { const char *name; void (*fn)(void); } unit_test;
#define UNIT(fn) { #fn, fn }

static inline int unit_run(const unit_test *t, size_t n)
{
    const char *only = getenv("UNIT_ONLY");
    for (size_t i = 0; i < n; i++) {
        if (only && strcmp(only, t[i].name) != 0)
            continue;
        unit_current = t[i].name;
        int before = unit_failed;
        t[i].fn();
        fprintf(stderr, "%s %s\n", unit_failed == before ? "ok  " : "FAIL", t[i].name);
    }
    printf("%d passed, %d failed\n", unit_passed, unit_failed);
    return unit_failed ? 1 : 0;
}

#define UNIT_MAIN(...) int main(void) { \
    static const unit_test tests_[] = { __VA_ARGS__ }; \
    return unit_run(tests_, sizeof tests_ / sizeof tests_[0]); }

/* hex string -> bytes; returns length */
static inline size_t unit_unhex(const char *hex, uint8_t *out, size_t cap)
{
    size_t n = 0;
    while (hex[0] && hex[1] && n < cap) {
        unsigned v;
        sscanf(hex, "%2x", &v);
        out[n++] = (uint8_t)v;
        hex += 2;
    }
    return n;
}
#endif

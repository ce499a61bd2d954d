// A minimal test harness for export/cpp/tests (no third-party framework): CHECK* macros record
// each failure with its file and line, and a test program returns report() from main (the
// number of failures; non-zero fails the ctest case).
#pragma once

#include <cmath>
#include <cstdio>
#include <sstream>
#include <string>

#include "slimseg/error.hpp"

namespace slimseg_test {

inline int& failures() {
    static int n = 0;
    return n;
}

inline void fail(const char* file, int line, const std::string& what) {
    std::fprintf(stderr, "%s:%d: FAILED %s\n", file, line, what.c_str());
    ++failures();
}

template <typename A, typename B>
void check_eq(const A& a, const B& b, const char* expr, const char* file, int line) {
    if (a == b) return;
    std::ostringstream s;
    s << expr << ": " << a << " != " << b;
    fail(file, line, s.str());
}

inline void check_near(double a, double b, double tol, const char* expr, const char* file,
                       int line) {
    if (std::fabs(a - b) <= tol) return;
    std::ostringstream s;
    s.precision(17);
    s << expr << ": " << a << " differs from " << b << " by more than " << tol;
    fail(file, line, s.str());
}

inline int report(const char* program) {
    if (failures() == 0) std::printf("%s: all checks passed\n", program);
    else std::fprintf(stderr, "%s: %d check(s) failed\n", program, failures());
    return failures() == 0 ? 0 : 1;
}

}  // namespace slimseg_test

#define CHECK(cond) \
    ((cond) ? void() : slimseg_test::fail(__FILE__, __LINE__, "CHECK(" #cond ")"))
#define CHECK_EQ(a, b) slimseg_test::check_eq((a), (b), #a " == " #b, __FILE__, __LINE__)
#define CHECK_NEAR(a, b, tol) \
    slimseg_test::check_near((a), (b), (tol), #a " ~ " #b, __FILE__, __LINE__)
// `expr` throws slimseg::Error whose message is exactly `message` (one line).
#define CHECK_ERROR(expr, message)                                                         \
    do {                                                                                   \
        try {                                                                              \
            expr;                                                                          \
            slimseg_test::fail(__FILE__, __LINE__, #expr ": no slimseg::Error thrown");    \
        } catch (const slimseg::Error& e_) {                                               \
            slimseg_test::check_eq(std::string(e_.what()), std::string(message),           \
                                   #expr " message", __FILE__, __LINE__);                  \
        }                                                                                  \
    } while (0)

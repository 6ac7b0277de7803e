// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_DEBUG_ASSERT(condition): an invariant of an internal data structure, checked only in
// builds made to find bugs. CMake defines CLASTRACE_DEBUG_LEVEL=1 for Debug, sanitizer
// (CLASTRACE_SANITIZE) and libFuzzer (CLASTRACE_FUZZ) builds, or when -DCLASTRACE_DEBUG_LEVEL=1
// asks for it (common/CMakeLists.txt). At level 0, the default of Release and RelWithDebInfo,
// the condition is not evaluated and costs nothing, though it still has to compile.
//
// A failed check prints file:line and the condition to stderr and aborts: the structure is
// already broken, so carrying on would only move the crash away from its cause. Checks are for
// our own mistakes; bad input gets a reported error, never an assert.
#pragma once

#ifndef CLASTRACE_DEBUG_LEVEL
#define CLASTRACE_DEBUG_LEVEL 0
#endif

#if CLASTRACE_DEBUG_LEVEL >= 1

#include <cstdio>
#include <cstdlib>

namespace clastrace::common {

[[noreturn]] inline void debug_assert_failed(const char* file, int line, const char* condition) {
    std::fprintf(stderr, "%s:%d: invariant broken: %s\n", file, line, condition);
    std::fflush(stderr);
    std::abort();
}

}  // namespace clastrace::common

#define CLASTRACE_DEBUG_ASSERT(condition) \
    ((condition) ? static_cast<void>(0)   \
                 : ::clastrace::common::debug_assert_failed(__FILE__, __LINE__, #condition))

#else

// sizeof keeps the condition compiled (so it cannot rot) but never evaluated.
#define CLASTRACE_DEBUG_ASSERT(condition) static_cast<void>(sizeof(!(condition)))

#endif

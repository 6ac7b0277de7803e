// SPDX-License-Identifier: Apache-2.0
// The trace files the replay tests write: one path per test process in TMPDIR
// (temp_trace_path.h), removed after use unless asked to keep them, and replayed with a trace
// that does not open failing the test.
#pragma once

#include <clastrace/replay/replayer.h>
#include <clastrace/testsupport/temp_trace_path.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

namespace clastrace::test {

// CLASTRACE_KEEP_TRACES=1 keeps the traces (e.g. to look at them with `clastrace replay`).
inline void discard_trace(const std::string& path) {
    if (!std::getenv("CLASTRACE_KEEP_TRACES")) std::remove(path.c_str());
}

// A damaged copy of a trace file's bytes: every third round cuts the tail (keeping at least
// 32 bytes), the other rounds flip 1 to 4 bits.
inline std::vector<char> damaged_copy(const std::vector<char>& bytes, int round,
                                      std::mt19937_64& rng) {
    std::vector<char> mutant = bytes;
    if (round % 3 == 2) {
        mutant.resize(32 + rng() % (mutant.size() - 32));
    } else {
        for (int k = 0, n = 1 + int(rng() % 4); k < n; ++k)
            mutant[rng() % mutant.size()] ^= char(1 << (rng() % 8));
    }
    return mutant;
}

inline replay::ReplayReport replay_file(const std::string& path,
                                        replay::ReplayOptions options = {}) {
    traces::TraceError e;
    auto reader = traces::TraceReader::open(path, &e);
    EXPECT_TRUE(reader) << e.message;
    if (!reader) return {};
    return replay::replay_trace(*reader, path, options);
}

}  // namespace clastrace::test

// SPDX-License-Identifier: Apache-2.0
// Drives every reader entry point over untrusted bytes; shared by the mutation test
// and the libFuzzer target so both cover the same paths.
#pragma once

#include <clastrace/traces/trace_reader.h>

#include <cstddef>
#include <cstdint>

namespace clastrace::traces::testing {

struct ExerciseResult {
    bool opened = false;
    uint64_t records = 0;
    uint64_t damage = 0;
};

// Opens `data` from memory, reads every record, touches the header, seeks to a few
// submissions and reads back the contents snapshots refer to.
ExerciseResult exercise_reader(const uint8_t* data, size_t size);

}  // namespace clastrace::traces::testing

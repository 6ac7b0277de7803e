// SPDX-License-Identifier: Apache-2.0
// Fuzz target: arbitrary bytes as a trace file, through every entry point of the reader
// (exercise_reader, shared with the traces mutation test). Crashes, sanitizer reports,
// timeouts and runaway memory are the findings. docs/fuzzing.md runs it.
#include "exercise_reader.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    clastrace::traces::testing::exercise_reader(data, size);
    return 0;
}

// libFuzzer entry point: arbitrary bytes as a trace file. Crashes, leaks, sanitizer
// reports and timeouts are the findings. Seed corpus: traces/samples/ and any .clt.
#include "exercise_reader.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    clastrace::traces::testing::exercise_reader(data, size);
    return 0;
}

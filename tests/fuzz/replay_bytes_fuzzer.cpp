// SPDX-License-Identifier: Apache-2.0
// Fuzz target: arbitrary bytes as the trace of `clastrace replay`: the reader's damage
// handling, the replayer's translation of whatever records survive, and both reports as the
// program prints them. Damage and faults must become findings, never a crash or a throw.
#include "fuzz_trace_name.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <nlohmann/json.hpp>

using namespace clastrace;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open_memory(data, size, kFuzzTraceName, &error);
    if (!reader) return 0;
    replay::ReplayOptions options;
    options.memory_budget_bytes = 64u << 20;  // a fuzzed bind may claim any size
    const replay::ReplayReport report = replay::replay_trace(*reader, kFuzzTraceName, options);
    (void)replay::format_text(report);
    // As tools/cmd_replay.cpp prints it: ill-formed UTF-8 replaced, never thrown.
    (void)replay::to_json(report).dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
    return 0;
}

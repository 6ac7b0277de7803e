// SPDX-License-Identifier: Apache-2.0
// Fuzz target: arbitrary bytes as the trace of `clastrace analyze`: the replay feeding the
// analyzer and the report in its three formats. analyze_trace throws AnalysisInputError only
// when the feeder breaks the analyzer's contract, so any throw is a finding.
#include "fuzz_trace_name.h"

#include <clastrace/analyze/render.h>
#include <clastrace/analyze/replay_stream.h>
#include <clastrace/traces/trace_reader.h>

using namespace clastrace;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    traces::TraceError error;
    auto reader = traces::TraceReader::open_memory(data, size, kFuzzTraceName, &error);
    if (!reader) return 0;
    analyze::AnalyzeOptions options;
    options.replay.memory_budget_bytes = 64u << 20;
    const analyze::TraceAnalysis analysis =
        analyze::analyze_trace(*reader, kFuzzTraceName, options);
    (void)analyze::render_text(analysis.report);
    (void)analyze::render_json(analysis.report);
    (void)analyze::render_html(analysis.report);
    return 0;
}

// SPDX-License-Identifier: Apache-2.0
// Streaming analysis of a trace: replay runs with a ReplayStreamFeeder as its observer, and
// the feeder turns each replayed command into analyzer events as it is replayed.
//
// What it feeds, per command (docs/analyze.md, "From a replay"):
//   - every submitted command except timestamps and labels: name, op type and mode, ops,
//     triangles (from the srcInfosArray elements in replay memory), engine time;
//   - regions: the bytes each acceleration-structure command touched, from the engine's
//     execution record (scratch, dstImplicitData, address/size arrays, src infos, vertex and
//     index data, objects) and the VkBuffers holding them; legacy NV builds and
//     deserializations from their records;
//   - objects: one per op that produced one, with the engine's size, the captured
//     dstSizesArray value as the driver size, triangles, vertices, truncate bits, and the size
//     rebuilt at positionTruncateBitCount 0 for the first few truncated objects of a command;
//   - the GetClusterBuildSizes answer whose input matches the command (else the latest one
//     with the same op type and mode);
//   - hazards as the sync model finds them (per-op hazards of one command folded);
//   - GPU time from GpuTimestamp pairs of one command buffer: a span per pair, and the span's
//     time as the command's gpu_ns when exactly one command that does work lies between;
//   - trace bytes from the records (snapshot bytes referenced vs contents stored) and the
//     reader's chunk statistics.
// Memory: the events of one submission are held until it ends (GPU time needs its closing
// timestamp), so the peak follows the largest submission, never the trace length.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "clastrace/analyze/analyzer.h"
#include "clastrace/replay/replay_observer.h"
#include "clastrace/replay/replayer.h"

namespace clastrace::traces {
class TraceReader;
struct TraceReadStats;
}  // namespace clastrace::traces

namespace clastrace::analyze {

struct StreamOptions {
    // Truncated CLAS/templates per command rebuilt at positionTruncateBitCount 0 to measure
    // what truncation saves (one more engine build each). 0 turns the measurement off.
    uint32_t untruncated_rebuilds_per_command = 8;
    // Commands remembered so a hazard can name its earlier command by ordinal.
    std::size_t hazard_window_commands = 65536;
};

struct StreamStats {
    uint64_t records = 0, submissions = 0, commands = 0, commands_fed = 0;
    uint64_t hazards = 0, hazards_merged = 0, hazards_prior_unknown = 0, findings = 0;
    uint64_t untruncated_rebuilds = 0;
    uint64_t largest_submission_events = 0;  // regions + objects + hazards held for one submission
    uint64_t peak_held_bytes = 0;            // estimate of what those events occupied
};

class ReplayStreamFeeder final : public replay::ReplayObserver {
public:
    // `contents` reads a MemoryContents by hash (captured output sizes); may be empty.
    ReplayStreamFeeder(Analyzer& analyzer, double timestamp_period_ns, bool period_known,
                       std::function<bool(uint64_t hash, std::vector<uint8_t>* bytes)> contents,
                       StreamOptions options = {});
    ~ReplayStreamFeeder() override;

    void on_record(const traces::RecordView& view) override;
    void on_submission_begin(uint32_t submission_index) override;
    void on_command(const replay::ReplayedCommand& command) override;
    void on_finding(const replay::ReplayFinding& finding) override;
    void on_hazard(const replay::HazardReport& hazard) override;
    void on_submission_end(uint32_t submission_index) override;

    // Feeds what is still held, the trace bytes and the notes. Call once, before Analyzer::finish().
    void finish(const traces::TraceReadStats& read_stats);
    const StreamStats& stats() const;

private:
    struct State;
    std::unique_ptr<State> state_;
};

struct AnalyzeOptions {
    AnalyzerLimits limits;
    StreamOptions stream;
    replay::ReplayOptions replay;  // its observer is replaced by the feeder
};

struct TraceAnalysis {
    AnalysisReport report;
    replay::ReplayReport
        replay;  // findings, hazards (merged), damage: what `clastrace replay` prints
    StreamStats stream;
};

// Replays `reader` from its current position with a feeder and returns the finished report.
// Throws AnalysisInputError only if the feeder broke the analyzer's contract (a bug).
TraceAnalysis analyze_trace(traces::TraceReader& reader, const std::string& trace_name,
                            const AnalyzeOptions& options = {});

}  // namespace clastrace::analyze

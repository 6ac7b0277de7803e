// SPDX-License-Identifier: Apache-2.0
// Analyzer: consumes a replayed trace as a stream of events and folds it into an
// AnalysisReport. Memory is bounded by the largest command (its pending overlap events and
// objects) plus fixed caps (AnalyzerLimits) plus the live address map, never by trace length.
//
// Event order, per command:
//   on_command(c)                          opens command c (ordinals strictly increase)
//   on_region / on_object / on_build_sizes / on_hazard, any number, in any order
// then the next on_command or finish() closes c. on_trace_bytes may come at any time.
// A hazard names (first_command, second_command = c); overlaps found while c is open are
// matched against the hazards of c when c closes: a matched overlap is a hazard, an unmatched
// one is safe, ordered reuse (or aliasing, if the lifetimes interleave).
//
// Events that break a rule (ordinal going backwards, a region passing the end of the address
// space, an object outside a command, ...) throw AnalysisInputError naming the rule and values.
#pragma once

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>

#include "clastrace/analyze/input.h"
#include "clastrace/analyze/report.h"

namespace clastrace::analyze {

class AnalysisInputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct AnalyzerLimits {
    std::size_t max_listed_commands = 512;
    std::size_t top_commands = 10;
    std::size_t timeline_buckets = 256;
    std::size_t max_tracked_regions = 8192;  // the memory map draws at most 3000 of them
    std::size_t max_listed_overlaps = 1024;  // plus up to max_listed_hazards pairs that are hazards
    std::size_t max_listed_hazards = 1024;
    std::size_t recent_command_rows = 256;  // kept so a hazard's first command can be listed
    std::size_t max_listed_gpu_spans = 1024;
};

class Analyzer {
public:
    explicit Analyzer(std::string trace_name = {}, AnalyzerLimits limits = {});
    ~Analyzer();
    Analyzer(const Analyzer&) = delete;
    Analyzer& operator=(const Analyzer&) = delete;

    void on_command(const CommandInfo& command);
    void on_region(const RegionInfo& region);
    void on_object(const ObjectInfo& object);
    void on_build_sizes(const BuildSizesInfo& sizes);
    void on_hazard(const HazardSummary& hazard);
    void on_trace_bytes(const TraceBytes& bytes);
    // Any time: a GPU timestamp pair's span (spans come in execution order), the device clock,
    // and notes for people (what could not be attributed; at most 64 kept).
    void on_gpu_span(const GpuSpan& span);
    void on_gpu_clock(const GpuClock& clock);
    void on_note(std::string note);

    // Closes the open command and returns the report; the Analyzer is spent afterwards.
    AnalysisReport finish();

private:
    struct State;
    std::unique_ptr<State> state_;
};

}  // namespace clastrace::analyze

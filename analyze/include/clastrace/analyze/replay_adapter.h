// Feeds an Analyzer from a finished replay. This round converts the ReplayReport after the
// replay ran, so it is not streaming: it sees what the report keeps, which is
//   - every cluster command (SizeComparison): ordinal = replay sequence, op type, op count;
//   - one object per op in SizeComparison::first_ops (the first kOpsListed ops of a command)
//     with the engine's size and the captured dstSizesArray size as the driver size;
//   - hazards whose two commands have a known sequence number (cluster commands, or commands
//     that also carry a finding or a not-replayed note); the rest are counted in
//     ReplayFeedStats::hazards_not_fed.
// Not known from the report, so not fed: regions, build-sizes queries, triangles, vertices,
// truncate bits, object addresses, replay/GPU time, non-cluster commands without findings.
#pragma once

#include <cstdint>

#include "clastrace/analyze/analyzer.h"

namespace clastrace::replay {
struct ReplayReport;
}

namespace clastrace::analyze {

struct ReplayFeedStats {
  uint64_t commands = 0;
  uint64_t objects = 0;
  uint64_t ops_without_sizes = 0;         // ops past first_ops or not compared: no object fed
  uint64_t hazards = 0;
  uint64_t hazards_not_fed = 0;  // a command of the pair has no known sequence or was left out
  uint64_t commands_out_of_order = 0;     // submission went backwards in sequence order: left out
};

// Emits the report's commands in sequence order with their objects and hazards. Does not
// call finish(). Throws AnalysisInputError only if the report breaks the analyzer's rules in
// a way the conversion did not foresee.
ReplayFeedStats feed_replay_report(const replay::ReplayReport& report, Analyzer& analyzer);

}  // namespace clastrace::analyze

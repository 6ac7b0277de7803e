// SPDX-License-Identifier: Apache-2.0
// ReplayObserver: what a replay does, one event at a time, for consumers that fold a trace as
// it streams (clastrace analyze) instead of reading the ReplayReport at the end.
//
// Order of events: on_record for every record the reader hands out, in file order. A
// QueueSubmit record is followed by on_submission_begin, then per command of the submission
// (queue order): the command's findings and hazards are found while it runs and handed out
// right after its on_command, then on_submission_end. Every pointer in an event is valid only
// during the call. Hazards are the SyncModel's, before replay folds per-op hazards into one
// report per command pair; hazards and findings past their caps (ReplayOptions) are counted
// in the ReplayReport only.
#pragma once

#include <cstdint>
#include <functional>

#include "clastrace/replay/hazard_report.h"
#include "clastrace/replay/replay_report.h"

namespace clastrace::fbs {
struct Record;
}
namespace clastrace::engine {
struct ExecutionRecord;
class MemoryImage;
}  // namespace clastrace::engine
namespace clastrace::traces {
struct RecordView;
}

namespace clastrace::replay {

struct ReplayedCommand {
    ReplayLocation where;
    const fbs::Record* record = nullptr;  // the captured command, as the trace holds it
    bool executed = false;                // false: outside ReplayOptions' --ops/--submit selection
    // Cluster builds the engine ran: every range read and written (with its field name), the
    // per-op results (object address, size) and the scratch/implicit bytes used. Null otherwise.
    const engine::ExecutionRecord* execution = nullptr;
    uint64_t engine_ns = 0;  // wall time of engine::execute (0 where the engine did not run)
    uint64_t replay_ns =
        0;  // wall time of the whole command's replay (sync model and checks included)
    // Replay memory after the command (inputs laid in, outputs written); for reading the
    // command's inputs, e.g. srcInfosArray elements.
    const engine::MemoryImage* memory = nullptr;
    // The engine's copy of acceleration structure `handle` in `memory` after the command (the
    // object replay built for it, at an address of its own): where engine::NvScene::open traces
    // rays through the replayed structures. 0 when replay holds no built object for it.
    std::function<uint64_t(uint64_t handle)> engine_structure_address;
};

class ReplayObserver {
public:
    virtual ~ReplayObserver() = default;
    virtual void on_record(const traces::RecordView& /*view*/) {}
    virtual void on_submission_begin(uint32_t /*submission_index*/) {}
    virtual void on_command(const ReplayedCommand& /*command*/) {}
    virtual void on_finding(const ReplayFinding& /*finding*/) {}
    virtual void on_hazard(const HazardReport& /*hazard*/) {}
    virtual void on_submission_end(uint32_t /*submission_index*/) {}
};

}  // namespace clastrace::replay

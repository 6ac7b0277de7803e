// SPDX-License-Identifier: Apache-2.0
// Structures read before anything built them (docs/replay.md, "Structures no command built"):
// a consumer or a top-level build reaching a created acceleration structure that no command of
// the trace built, copied or deserialized into, nor the pre-range prelude of a frame range.
// Without this rule only the engine's ray check notices (its rays miss).
#include "hazard_text.h"
#include "replayer_internal.h"

#include <clastrace/common/hex.h>

namespace clastrace::replay::detail {

using common::hex;

namespace {

constexpr const char* kRuleStructureNotBuilt = "CLASTRACE-replay-structure-not-built";

}  // namespace

// The command at `where`, in the one text hazards and findings name commands by
// (command_place_text): "vkCmdTraceRaysKHR (queue 0, submit 3, cb 0, cmd 2, frame 4)".
std::string Replay::command_text(const ReplayLocation& where) const {
    return command_place_text(command_ref(where), where.queue, frames_.frame_of(where.submission));
}

// Every command the trace submits, replayed or outside the selection: what it writes is built
// from then on (a slice's consumer must not blame a build the slice skipped).
void Replay::note_structure_writes(const fbs::Record& record) {
    switch (record.body_type()) {
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        reachability_.on_written(record.body_as_CmdBuildAccelerationStructureNV()->dst());
        break;
    case fbs::RecordBody::CmdBuildAccelerationStructuresKHR:
        if (const auto* infos = record.body_as_CmdBuildAccelerationStructuresKHR()->infos())
            for (const fbs::AccelerationStructureBuildInfoKHR* info : *infos)
                reachability_.on_written(info->dst());
        break;
    case fbs::RecordBody::CmdCopyAccelerationStructure:
        reachability_.on_written(record.body_as_CmdCopyAccelerationStructure()->dst());
        break;
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        reachability_.on_written(record.body_as_CmdCopyMemoryToAccelerationStructure()->dst());
        break;
    default: break;
    }
}

// Why a structure no command built is read, as far as the trace tells.
std::string Replay::unbuilt_cause() const {
    if (pre_range_)
        return "the trace's pre-range state (the builds kept from before frame " +
               std::to_string(pre_range_->before_frame) +
               ") does not hold it either, so it was never built, or built by a command the "
               "capture did not keep (a cluster build, or one whose memory was freed)";
    return "it was built before the captured range by a capture without pre-range state (a "
           "layer older than format 1.5, or CLASTRACE_SUBMIT_RANGE), or it was never built: "
           "capture from the first frame, or with CLASTRACE_FRAME_RANGE so the layer writes the "
           "state from before the range";
}

// `reader` reads `s` (a structure it reaches): a finding the first time for each structure
// until a command builds it.
void Replay::check_structure_built(const ReachedStructure& s, const std::string& reader,
                                   const ReplayLocation& where) {
    if (s.handle == 0 || s.written || !unbuilt_told_.insert(s.handle).second) return;
    add_finding({kRuleStructureNotBuilt,
                 reader + " reads acceleration structure " + hex(s.handle) + " (" + s.path +
                     "), which no command of the trace built, copied or deserialized into: " +
                     unbuilt_cause() + ". What it reads is undefined; the driver may return no " +
                     "hits or lose the device.",
                 FindingSource::kReplay, where, -1, s.range.begin});
}

// A consumer's bindings: each structure reachable from them, built or not.
void Replay::check_consumer_structures_built(const ConsumerBindings* bindings,
                                             const ReplayLocation& where) {
    if (!bindings) return;
    for (size_t i = 0; i < bindings->size(); ++i) {
        const fbs::AccelerationStructureBinding* b =
            bindings->Get(static_cast<flatbuffers::uoffset_t>(i));
        for (const ReachedStructure& s :
             reachability_.reach(b->acceleration_structure(), b->address(), ""))
            check_structure_built(s, command_text(where), where);
    }
}

// A top-level build of `top`: the bottom levels its instances name must hold a build.
void Replay::check_instances_built(uint64_t top, const ReplayLocation& where) {
    for (const ReachedStructure& s : reachability_.reach(top, 0, ""))
        if (s.handle != top)
            check_structure_built(s, command_text(where) + ", building top level " + hex(top),
                                  where);
}

}  // namespace clastrace::replay::detail

// SPDX-License-Identifier: Apache-2.0
// Pre-range state of cluster objects (layer_pre_range.h, capture/README.md "Frame ranges"): the
// vkCmdBuildClusterAccelerationStructureIndirectNV commands (served or not) made before
// CLASTRACE_FRAME_RANGE starts whose objects may still be used in it, with their captures.
// Cluster objects are address ranges, not handles: a command's objects are the dstObject ranges
// of its capture, and a later command writing over one of them ends it.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "pause_worker.h"

#include <cstdint>
#include <map>
#include <optional>
#include <tuple>
#include <utility>
#include <vector>

namespace clastrace::capture {

// Whether a cluster command writes objects: every operation but sizes-only ones and
// template-index queries.
bool writes_cluster_objects(const ClusterCommandParameters& parameters);

// Before a capture is kept (outside the store's lock, on the pause worker's thread): a served
// one is completed (its outputs walked in the engine's image) and every range gets its own
// copy of its bytes, so the engine's image goes back instead of staying until the range starts.
void prepare_kept_cluster_capture(ClusterBuildCapture& capture);

// The kept cluster commands of one device, in execution order. Not thread-safe: the pre-range
// store's lock guards it.
class PreRangeClusterCommands {
public:
    using Key = std::tuple<uint64_t, uint64_t, uint32_t>;  // submission, pause, occurrence

    // Submission order: command `key` ran after every one noted before it.
    void note(const Key& key, ClusterBuildCommand command);
    bool expects(const Key& key) const { return sequence_of_.count(key) != 0; }
    // The capture of a noted command came (prepared): its objects are known, and commands whose
    // objects all were overwritten meanwhile go.
    void arrived(const Key& key, ClusterBuildCapture capture);
    // The memory under [begin, end) was freed now: objects there end, as if overwritten by a
    // command that reads none (also those of captures that come later).
    void freed(uint64_t begin, uint64_t end);
    size_t arrived_count() const;            // noted commands whose capture came
    std::vector<Key> still_to_come() const;  // noted commands whose capture has not come
    size_t size() const { return kept_.size(); }
    uint32_t live_objects() const;  // objects no later command overwrote (or unknown: counted 1)
    uint64_t bytes(bool outputs) const;  // bytes their captures hold: outputs, or inputs

    struct Taken {
        Key key;
        ClusterBuildCommand command;
        std::optional<ClusterBuildCapture> capture;
    };
    std::vector<Taken> take();  // in execution order; empty afterwards

private:
    struct Object {
        uint64_t begin = 0, end = 0;
        uint64_t overwritten_by = 0;  // the sequence of the first later command writing over it
    };
    struct Kept {
        Key key;
        ClusterBuildCommand command;
        std::optional<ClusterBuildCapture> capture;
        std::vector<Object> objects;  // empty until the capture came (or when it names none)
    };
    struct Freed {
        uint64_t begin = 0, end = 0, sequence = 0;
    };
    void overwrite(Kept& older, const Kept& newer, uint64_t newer_sequence);
    void end_freed(Kept& k, uint64_t sequence, const Freed& f);
    void drop_overwritten();

    std::map<uint64_t, Kept> kept_;  // by execution sequence
    std::map<Key, uint64_t> sequence_of_;
    std::vector<Freed> freed_;  // in order, for captures still to come
    uint64_t next_sequence_ = 1;
};

}  // namespace clastrace::capture

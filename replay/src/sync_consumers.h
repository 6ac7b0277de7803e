// SPDX-License-Identifier: Apache-2.0
// Consumers of acceleration structures in the synchronization model (docs/replay.md,
// "Consumers"): the frame each submission belongs to, and what a hazard or finding about a
// consumer tells the user beyond the barrier (the frames, a fence wait, a double-buffered pool).
#pragma once

#include <clastrace/replay/hazard_report.h>

#include <cstdint>
#include <optional>
#include <string_view>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

// Every structure read a consumer records names its binding with this prefix:
// "acceleration_structures[0] (set 0, binding 1): top level 0xa5003 > instance 2: ...".
inline constexpr std::string_view kConsumerField = "acceleration_structures[";
bool is_consumer_read(const HazardAccess& access);

// Frames of a trace, told by its frame boundaries. Today those are the QueuePresent records
// (format 1.2); a headless program's boundary record goes through on_boundary too, so every
// frame number in a report comes from frame_of.
class FrameBoundaries {
public:
    // Frame `frame` ended after `submissions_before` submissions (the next submission_index).
    void on_boundary(uint64_t frame, uint32_t submissions_before);
    // Submission `submission` is a frame range's pre-range prelude (PreRangeState, format 1.5).
    void on_pre_range(uint32_t submission) { prelude_ = submission; }
    // The frame submission `submission` belongs to; nullopt in a trace without boundaries and
    // for the pre-range prelude.
    std::optional<uint64_t> frame_of(uint32_t submission) const;

private:
    std::vector<std::pair<uint32_t, uint64_t>> ends_;  // (submissions before it, frame), in order
    std::optional<uint32_t> prelude_;
};

// Gives each side of each hazard its frame, and a hazard between a consumer and a build or copy
// of another frame the fix that frame-level code needs (a fence wait, double-buffering).
void annotate_consumer_hazards(std::vector<HazardReport>& hazards, const FrameBoundaries& frames);

}  // namespace clastrace::replay::detail

// SPDX-License-Identifier: Apache-2.0
// A synchronization hazard found in a captured stream, and how to print it.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "clastrace/replay/sync_types.h"

namespace clastrace::replay {

enum class HazardClass : uint8_t {
    kReadAfterWrite,
    kWriteAfterWrite,
    kWriteAfterRead,
    kMoveOverlap,       // one command's source and destination overlap
    kDeserializeInUse,  // deserialization into memory whose earlier accesses are not ordered before it
};
// "READ-AFTER-WRITE", ... (the validation layers' SYNC-HAZARD-* spelling).
const char* hazard_class_name(HazardClass c);

// How the two accesses relate in time, which decides the kind of fix.
enum class FixKind : uint8_t {
    kPipelineBarrier,     // same queue: a barrier between them
    kSemaphore,           // different queues: a semaphore signal/wait
    kHostWait,            // device access then host access: wait on the submission's fence first
    kHostWaitAndBarrier,  // host reads a device write: barrier to HOST/HOST_READ, then a fence wait
    kDisjointRanges,      // no barrier helps: use non-overlapping ranges
};

struct FixingBarrier {
    FixKind kind = FixKind::kPipelineBarrier;
    StageMask src_stages = 0;
    AccessMask src_access = 0;
    StageMask dst_stages = 0;
    AccessMask dst_access = 0;
    // The sentence a user reads, e.g. "vkCmdPipelineBarrier2 with a VkMemoryBarrier2 {...}".
    std::string describe() const;
};

struct HazardAccess {
    CommandRef command;
    QueueId queue = 0;
    StageMask stage = 0;
    AccessMask access = 0;
    bool is_write = false;
    bool possible = false;  // an access the trace only allows (Access::possible)
    AddressRange range;     // the whole range this access covered
    std::string field;
    std::optional<uint64_t> frame;  // the frame of its submission, where the trace tells frames
};

struct HazardReport {
    HazardClass hazard = HazardClass::kReadAfterWrite;
    HazardAccess prior;    // the earlier access (for kMoveOverlap: the source)
    HazardAccess later;    // the access that found the hazard (for kMoveOverlap: the destination)
    AddressRange overlap;  // bytes both touch
    FixingBarrier fix;
    // What else fixes it, beyond the barrier: for a consumer of acceleration structures, the
    // frame-level fix (a fence wait before rebuilding, a double-buffered pool). May be empty.
    std::string advice;
    // Possible, not certain: one side is an access the trace only allows (a dispatch that may
    // write through device addresses), so the bytes may never have been touched.
    bool possible() const { return prior.possible || later.possible; }
    std::string format() const;
};
// "SYNC-HAZARD-READ-AFTER-WRITE", or "POSSIBLE-SYNC-HAZARD-READ-AFTER-WRITE" for a possible one:
// the name summaries count it under, so possible hazards are counted apart from certain ones.
std::string hazard_rule_name(const HazardReport& report);

// The field a hazard names, without its op index or its size note, so that the hazards one
// missing barrier causes over one field fold into one report:
// "srcInfosArray[3].vertexBuffer" -> "srcInfosArray[*].vertexBuffer",
// "dstImplicitData[op 3]" and "dstImplicitData (the 4096-byte implicit region ...)" ->
// "dstImplicitData".
std::string hazard_field_family(const std::string& field);

// The field of two folded hazards: the same field stays, two op indices become [*], and the
// size note one of them carries is kept.
std::string folded_hazard_field(const std::string& a, const std::string& b);

nlohmann::json to_json(const HazardReport& report);
nlohmann::json to_json(const std::vector<HazardReport>& reports, uint64_t suppressed);

}  // namespace clastrace::replay

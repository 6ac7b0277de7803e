// SPDX-License-Identifier: Apache-2.0
// What a replay found: rule violations (VUIDs and clastrace rules, each at the command
// and op that broke it), synchronization hazards, mismatches between the capturing
// side's outputs and the engine's; and, apart from those, notes: the limits of the replay
// itself (what it cannot decode or did not replay), which never make a trace unclean.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "clastrace/replay/hazard_report.h"

namespace clastrace::replay {

// Where in the captured stream a finding was made.
struct ReplayLocation {
    uint64_t sequence = 0;        // execution order of the command over the whole replay (--ops)
    uint32_t submission = 0;      // QueueSubmit submission_index
    uint32_t command_buffer = 0;  // command buffer within that submission
    uint32_t command = 0;         // command within its command buffer
    uint64_t command_buffer_handle = 0;
    const char* name = "";  // Vulkan command name
    // Inside a secondary command buffer (as CommandRef): `command` is the vkCmdExecuteCommands.
    uint64_t secondary_handle = 0;
    uint32_t secondary = 0;
    uint32_t secondary_command = 0;
    // The queue it ran on (queues numbered in the order the trace first submits to them), or
    // kHostQueue for a call of the host's (vkFreeMemory, vkAcquireNextImageKHR, ...).
    QueueId queue = kHostQueue;
};

enum class FindingSource : uint8_t {
    kEngine,  // a rule the engine checked while executing the command (VUID-... / CLASTRACE-...)
    kVerify,  // the capturing side's outputs differ from the engine's
    kReplay,  // the trace itself cannot be replayed as recorded (unknown object or buffer)
};
const char* finding_source_name(FindingSource source);

// Rules that name a limit of the replay or its engine, not a fault of the application or the
// trace: another driver's serialized object the engine cannot decode, the replay's memory
// budgets, a reference to an object built before the capture began, a cluster larger than the
// engine's format, findings past the per-rule cap. Reported as notes, never as findings.
bool is_replay_limit(std::string_view rule);

// A VkClusterAccelerationStructureOpTypeNV's name ("build_triangle_cluster", ...; "other" for
// any other value): the one table `clastrace replay` and `clastrace analyze` both print.
const char* cluster_op_type_name(uint32_t op_type);

struct ReplayFinding {
    std::string rule;  // VUID string verbatim, or CLASTRACE-...
    std::string message;
    FindingSource source = FindingSource::kEngine;
    ReplayLocation where;
    int64_t op_index = -1;  // element of srcInfosArray, -1 for the command as a whole
    uint64_t address = 0;
    // "VUID-...: vkCmd... (queue 0, submit 0, cb 0 (0x4001), cmd 3) [#8], op 2: message"
    std::string format() const;
};

// One cluster command's sizes, capturing side next to the engine (the side-by-side table).
struct SizeComparison {
    ReplayLocation where;
    uint32_t op_type = 0;
    uint32_t ops = 0;             // ops executed by the engine
    uint32_t ops_compared = 0;    // ops whose captured size was in the trace
    uint64_t captured_bytes = 0;  // sum of captured dstSizesArray entries (ops_compared)
    uint64_t engine_bytes = 0;    // sum of the engine's sizes for the same ops
    uint32_t sizes_equal = 0;     // ops with captured size == engine size
    // The sizes the model gave the command's ranges: buildScratchSize and
    // accelerationStructureSize (implicit: the region; explicit: one object) of the matching
    // build-size query, or, with spans_queried false, the engine's worst case assumed.
    uint64_t scratch_span = 0;
    uint64_t destination_span = 0;
    bool spans_queried = false;
    struct OpSize {
        uint32_t op = 0;
        uint32_t captured = 0;
        uint64_t engine = 0;
    };
    std::vector<OpSize> first_ops;  // the first kOpsListed compared ops, one by one
    static constexpr size_t kOpsListed = 64;
};

// One VkAccelerationStructureNV build: the capturing driver's memory requirement (when the
// trace holds it) next to the engine's requirement and the bytes its object took.
struct NvSizeComparison {
    ReplayLocation where;
    uint64_t handle = 0;
    bool top_level = false;
    uint64_t primitives = 0;     // triangles/AABBs given, or instances
    uint64_t driver_object = 0;  // 0: not captured
    uint64_t driver_build_scratch = 0;
    uint64_t engine_object = 0;  // the engine's requirement for the creation info
    uint64_t engine_build_scratch = 0;
    uint64_t engine_bytes = 0;  // the object the engine built
};

// One RayQueryCheck record: the capture's rays traced through the rebuilt top level.
struct RayCheckResult {
    std::string label;
    uint64_t acceleration_structure = 0;
    uint64_t after_submission = 0;
    bool checked = false;  // false: `why_not` says why no ray was traced
    std::string why_not;
    uint64_t rays = 0;
    uint64_t agree_miss = 0, agree_hit = 0;
    uint64_t float_precision = 0;  // of agree_hit: same primitive, t off by more than 1e-5
                                   // relative but within the engine's float32 error bound,
                                   // or barycentrics off by more than 1e-3 but within theirs
    uint64_t tie = 0;              // other primitive at the same t (shared edges, overlaps)
    uint64_t edge = 0;             // hit/miss or primitive differs within 1e-5 of an edge
    uint64_t disagree = 0;         // each one also a finding (up to the cap)
    // Of `disagree`, by cause class (each finding names its class too): the float32 error of
    // the hit is large (far away or tiny primitives, huge coordinates); the ray or the hit
    // primitive has NaN or zero-area geometry; none of those.
    uint64_t disagree_far_tiny = 0, disagree_degenerate = 0, disagree_unexplained = 0;
    std::string traversal;  // the engine's TraversalMode for these rays: "float32" or "double"
    double max_rel_t = 0;
};

// A limit met at one command (is_replay_limit): what the replay could not do there.
struct ReplayNote {
    std::string rule;  // CLASTRACE-... naming the limit
    std::string message;
    ReplayLocation where;
    int64_t op_index = -1;
    uint64_t address = 0;
    // "CLASTRACE-...: vkCmd... (queue 0, submit 0, cb 0 (0x4001), cmd 3) [#8]: message"
    std::string format() const;
};

struct NotReplayed {
    ReplayLocation where;
    std::string reason;
};

struct ReplayCounts {
    uint64_t records = 0;
    uint64_t submissions = 0;
    uint64_t commands = 0;           // commands executed (inside --ops/--submit)
    uint64_t cluster_commands = 0;   // vkCmdBuildClusterAccelerationStructureIndirectNV executed
    uint64_t cluster_ops = 0;        // ops they ran
    uint64_t copies = 0;             // copy/fill/update commands applied to memory
    uint64_t barriers = 0;           // barrier/event commands fed to the sync model
    uint64_t accesses = 0;           // accesses fed to the sync model
    uint64_t snapshots_applied = 0;  // captured memory snapshots laid into the image
    uint64_t snapshot_bytes = 0;
    uint64_t snapshots_outside_memory = 0;  // snapshots no bound buffer holds (skipped)
    // Served traceable cluster BLASes: driver BVH ranges the trace marked, and the bytes of later
    // snapshots over them that replay did not lay in (the engine's object stays).
    uint64_t driver_bvh_ranges = 0;
    uint64_t driver_bvh_bytes_kept = 0;
    uint64_t outputs_compared = 0;  // captured output snapshots compared byte for byte
    uint64_t output_bytes_compared = 0;
    uint64_t addresses_translated = 0;  // object addresses rewritten captured -> rebuilt
    uint64_t skipped_commands = 0;      // commands outside --ops/--submit
    uint64_t peak_image_bytes = 0;      // most bytes the memory image held at once (resident pages)
    uint64_t nv_builds = 0;             // vkCmdBuildAccelerationStructureNV executed by the engine
    uint64_t deserializations = 0;      // vkCmdCopyMemoryToAccelerationStructureKHR executed
    uint64_t handles_translated = 0;    // instance/serialized handles mapped to rebuilt objects
    uint64_t presents = 0;              // vkQueuePresentKHR records (format 1.2)
    uint64_t acquires = 0;              // vkAcquireNextImage[2]KHR records (format 1.2)
    // Semaphore waits of submissions whose signal the trace does not hold (SyncStats): such a
    // wait orders nothing in the hazard check. 0 with --no-hazards (not counted).
    uint64_t unsatisfied_semaphore_waits = 0;
    uint64_t khr_builds = 0;     // vkCmdBuildAccelerationStructures[Indirect]KHR executed
    uint64_t khr_copies = 0;     // acceleration-structure copies and serializations executed
    uint64_t query_answers = 0;  // property-query answers compared with the driver's
};

struct ReplayReport {
    std::string trace;          // file name as given
    bool engine_trace = false;  // made by clastrace's own engine: outputs compared byte-exactly
    std::string device;         // capturing device name
    std::vector<ReplayFinding> findings;
    uint64_t findings_over_cap = 0;
    std::vector<HazardReport> hazards;
    uint64_t hazards_over_cap = 0;  // over the cap (SyncStats)
    uint64_t hazards_merged =
        0;  // per-op hazards folded into one report per command pair and field
    bool hazards_checked = true;
    bool verified = true;
    std::vector<SizeComparison> sizes;
    std::vector<NotReplayed> not_replayed;
    uint64_t rows_over_cap = 0;  // sizes and not_replayed rows past ReplayOptions::max_command_rows
    std::vector<NvSizeComparison> nv_sizes;
    std::vector<RayCheckResult> ray_checks;
    std::vector<std::string> trace_damage;  // TraceError messages met while reading
    // Limits of the replay (is_replay_limit), kept apart from the findings: they never make
    // the report unclean, and `clastrace replay` exits 0 on a trace with notes only.
    std::vector<ReplayNote> notes;
    uint64_t notes_over_cap = 0;
    ReplayCounts counts;

    bool clean() const { return findings.empty() && hazards.empty() && trace_damage.empty(); }
};

// Text: one line per finding (rule first, as the validation layers print), the notes apart
// under "Notes", then a summary.
std::string format_text(const ReplayReport& report);
nlohmann::json to_json(const ReplayReport& report);

}  // namespace clastrace::replay

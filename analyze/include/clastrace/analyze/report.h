// SPDX-License-Identifier: Apache-2.0
// AnalysisReport: everything the renderers print. Sizes are bytes, times nanoseconds.
// Lists are bounded (see AnalyzerLimits); each bounded list says how many rows it left out.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "clastrace/analyze/input.h"
#include "clastrace/analyze/value_distribution.h"

namespace clastrace::analyze {

// 2: commands are every submitted command (copies, barriers, legacy builds), not only cluster
// builds; two reads of the same bytes are no longer an overlap.
inline constexpr int kReportSchemaVersion = 2;

struct OpTypeSizes {
    OpType op_type = OpType::kOther;
    uint64_t commands = 0;
    uint64_t ops = 0;
    uint64_t objects = 0;
    uint64_t triangles = 0;  // of the objects
    uint64_t vertices = 0;
    ValueDistribution engine_bytes;  // per object
    ValueDistribution driver_bytes;  // per object, only objects whose driver size was captured
    uint64_t objects_with_driver_bytes = 0;
    uint64_t engine_bytes_of_driver_objects = 0;  // engine bytes of exactly those objects
    // Build-sizes worst case vs actual, over the commands that came with a query.
    uint64_t commands_with_query = 0;
    uint64_t worst_case_bytes = 0;
    uint64_t actual_bytes_of_queried = 0;
    // dstImplicitData (implicit mode) and scratch: allocated region bytes vs used/required.
    uint64_t implicit_allocated = 0;
    uint64_t implicit_used = 0;
    uint64_t scratch_allocated = 0;
    uint64_t scratch_required = 0;  // build_scratch_size of the query, where known
    uint64_t scratch_used = 0;      // engine's scratch use, where replay reported it
    // Timing.
    uint64_t replay_ns = 0, replay_ops = 0, replay_triangles = 0;
    uint64_t gpu_ns = 0, gpu_ops = 0, gpu_triangles = 0, gpu_commands = 0;
};

struct TruncationRow {
    uint32_t truncate_bits = 0;
    uint64_t objects = 0;
    uint64_t triangles = 0;
    uint64_t engine_bytes = 0;
    uint64_t objects_with_untruncated = 0;
    uint64_t engine_bytes_of_those = 0;  // truncated size of the objects below
    uint64_t untruncated_bytes = 0;      // same objects at truncate bits 0
};

struct CommandRow {
    uint64_t ordinal = 0, submission = 0, command_buffer = 0;
    uint32_t index = 0;
    std::string name;
    OpType op_type = OpType::kOther;
    OpMode op_mode = OpMode::kNone;
    uint64_t op_count = 0, triangles = 0, objects = 0;
    uint64_t engine_bytes = 0;
    uint64_t driver_bytes = 0;                 // sum over objects with a captured driver size
    std::optional<uint64_t> worst_case_bytes;  // from the build-sizes query
    uint64_t implicit_allocated = 0, scratch_allocated = 0;
    std::optional<uint64_t> scratch_required, scratch_used;
    std::optional<uint64_t> gpu_ns, replay_ns;
    uint64_t hazards = 0;
};

struct TimelineBucket {  // a run of consecutive commands; one command each when few
    uint64_t first_ordinal = 0, last_ordinal = 0;
    uint64_t commands = 0, ops = 0, triangles = 0;
    uint64_t replay_ns = 0, gpu_ns = 0, gpu_commands = 0;
};

struct RegionRow {
    uint64_t id = 0;
    std::string label;
    uint64_t base = 0, size = 0;
    RegionRole role = RegionRole::kOther;
    uint64_t first_command = 0, last_command = 0;
    uint64_t uses = 0;
    bool written = false;
};

enum class OverlapKind : uint8_t {
    kAliasing,  // lifetimes interleave: both regions are in use around the same commands
    kReuse,     // the older region was done before the newer one took its bytes
};

struct OverlapRow {  // one pair of regions (older owner, newer user) that shared bytes
    uint64_t older_region = 0, newer_region = 0;
    std::string older_label, newer_label;
    RegionRole older_role = RegionRole::kOther, newer_role = RegionRole::kOther;
    uint64_t older_command = 0, newer_command = 0;  // commands of the first event of the pair
    uint64_t base = 0, size = 0;  // bounding range of the shared bytes over the pair's events
    uint64_t events = 0;
    OverlapKind kind = OverlapKind::kReuse;
    bool hazard = false;
    std::string hazard_class;
    std::optional<uint64_t> hazard_index;  // into AnalysisReport::hazards, when listed
};

struct OverlapSummaryRow {  // all overlap events, listed or not, by roles, kind and safety
    RegionRole older_role = RegionRole::kOther, newer_role = RegionRole::kOther;
    OverlapKind kind = OverlapKind::kReuse;
    bool hazard = false;
    uint64_t events = 0, bytes = 0;
};

struct HazardRow {
    uint64_t index = 0;
    HazardSummary hazard;
    uint64_t matched_overlaps = 0;  // overlap events this hazard explains
};

struct CommandKindRow {  // every command kind the trace submitted, by Vulkan name
    std::string name;
    uint64_t commands = 0, ops = 0, triangles = 0, objects = 0;
    uint64_t engine_bytes = 0, driver_bytes = 0;  // objects' bytes (driver: captured sizes and
        // the driver_object_bytes of commands not rebuilt)
    uint64_t replay_ns = 0, replay_commands = 0, gpu_ns = 0, gpu_commands = 0;
    uint64_t hazards = 0;
};

struct GpuSpanRow {
    GpuSpan span;
    uint64_t start_ns = 0;                  // after the first listed span's start
    std::optional<uint64_t> host_start_ns;  // on the host clock (GpuClock calibration)
};

struct AnalysisReport {
    int schema_version = kReportSchemaVersion;
    std::string trace_name;

    uint64_t commands = 0, submissions = 0, ops = 0, objects = 0, triangles = 0;
    uint64_t largest_submission = 0;  // submission index with the most ops (ties: first)
    uint64_t largest_submission_commands = 0, largest_submission_ops = 0;
    uint64_t regions = 0, region_uses = 0;
    uint64_t region_uses_not_tracked = 0;  // uses of regions beyond max_tracked_regions

    std::array<OpTypeSizes, kOpTypeCount> by_op_type{};  // indexed by OpType
    std::vector<TruncationRow> truncation;               // ascending truncate_bits, objects > 0
    std::optional<TraceBytes> trace_bytes;

    std::vector<CommandKindRow> command_kinds;  // in order of first appearance, at most 64 names
    uint64_t command_kinds_not_listed = 0;      // commands of names past that cap

    std::vector<CommandRow> commands_listed;  // first max_listed_commands, ordinal order
    uint64_t commands_not_listed = 0;
    std::vector<CommandRow> top_by_gpu;     // most GPU time first (commands with gpu_ns)
    std::vector<CommandRow> top_by_replay;  // most replay engine time first
    std::vector<TimelineBucket> timeline;
    bool gpu_timing_present = false, replay_timing_present = false;
    std::optional<GpuClock> gpu_clock;
    std::vector<GpuSpanRow> gpu_spans;  // first max_listed_gpu_spans, in order
    uint64_t gpu_spans_total = 0, gpu_spans_ns = 0, gpu_spans_ops = 0, gpu_spans_triangles = 0;

    std::vector<std::string> notes;  // what the feeder could not attribute (at most 64)

    std::vector<RegionRow> region_rows;      // tracked regions, by first use then address
    std::vector<OverlapRow> overlaps;        // first max_listed_overlaps pairs
    uint64_t overlap_events_not_listed = 0;  // events of pairs beyond max_listed_overlaps
    std::vector<OverlapSummaryRow> overlap_summary;
    uint64_t overlap_events = 0, overlap_hazard_events = 0;

    std::vector<HazardRow> hazards;  // first max_listed_hazards
    uint64_t hazards_total = 0;
    uint64_t hazards_not_listed = 0;

    const OpTypeSizes& sizes(OpType t) const { return by_op_type[static_cast<int>(t)]; }
};

// Names used by every renderer and in JSON (stable: changing one bumps schema_version).
const char* op_type_name(OpType t);   // "build_triangle_cluster", ...
const char* op_type_short(OpType t);  // "clas", "blas", ... (text tables)
const char* op_mode_name(OpMode m);
const char* region_role_name(RegionRole r);
const char* object_type_name(ObjectType t);
const char* overlap_kind_name(OverlapKind k);

}  // namespace clastrace::analyze

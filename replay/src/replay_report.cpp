// SPDX-License-Identifier: Apache-2.0
#include "clastrace/replay/replay_report.h"
#include "clastrace/common/hex.h"
#include "hazard_text.h"

#include <clastrace/engine/execute.h>
#include <clastrace/engine/finding.h>
#include <clastrace/engine/nv_serialize.h>
#include <clastrace/traces/utf8_text.h>
#include <clastrace/vk_cluster_abi.h>
#include <nlohmann/json.hpp>

#include <cinttypes>
#include <cstdio>
#include <map>
#include <string_view>

namespace clastrace::replay {

namespace {

using common::hex;

nlohmann::json where_json(const ReplayLocation& w) {
    nlohmann::json j = {{"sequence", w.sequence},
                        {"submission", w.submission},
                        {"command_buffer", w.command_buffer},
                        {"command_buffer_handle", hex(w.command_buffer_handle)},
                        {"command", w.command},
                        {"name", w.name}};
    if (w.secondary_handle)
        j["secondary"] = {{"index", w.secondary},
                          {"command_buffer_handle", hex(w.secondary_handle)},
                          {"command", w.secondary_command}};
    return j;
}

// "s0 cb1 cmd3 [#8]", or "s0 cb1 cmd3>0.1 [#8]" for command 1 of secondary 0 of execute 3.
std::string short_where(const ReplayLocation& w) {
    std::string command = std::to_string(w.command);
    if (w.secondary_handle)
        command += ">" + std::to_string(w.secondary) + "." + std::to_string(w.secondary_command);
    return "s" + std::to_string(w.submission) + " cb" + std::to_string(w.command_buffer) + " cmd" +
           command + " [#" + std::to_string(w.sequence) + "]";
}

}  // namespace

const char* finding_source_name(FindingSource source) {
    switch (source) {
    case FindingSource::kEngine: return "engine";
    case FindingSource::kVerify: return "verify";
    case FindingSource::kReplay: return "replay";
    }
    return "unknown";
}

bool is_replay_limit(std::string_view rule) {
    // Each one says what the replay could not do, never what the application did wrong: a
    // correct application's trace may meet any of them (docs/replay.md, "Notes").
    static constexpr std::string_view kLimits[] = {
        engine::kRuleSerializedOpaque,        // another driver's serialized object: not decoded
        engine::kRuleBeyondEngineFormat,      // more than the engine's 256 per cluster
        engine::kRuleUnsupportedFormat,       // a vertex format the engine does not read
        engine::kRuleFindingsTruncated,       // findings of one rule past the per-command cap
        "CLASTRACE-replay-nv-opaque-object",  // dst now holds such an object
        "CLASTRACE-replay-nv-object-over-budget",     // NV objects past the replay's budget
        "CLASTRACE-replay-memory-budget",             // buffers or writes past the budget
        "CLASTRACE-replay-command-buffer-dropped",    // recordings past max_recorded_bytes
        "CLASTRACE-replay-reference-not-rebuilt",     // an object built before the capture
        "CLASTRACE-replay-snapshot-outside-memory",   // captured bytes no buffer of it holds
        "CLASTRACE-replay-engine-failed",             // the engine stopped on the command
        "CLASTRACE-replay-sparse-bind-budget",        // sparse binds past the parts kept
        "CLASTRACE-replay-khr-query-answer-differs",  // engine layout vs the driver's
        "CLASTRACE-replay-khr-serialized-past-dst",   // the engine's blob outgrows the driver's
    };
    for (std::string_view limit : kLimits)
        if (rule == limit) return true;
    return false;
}

const char* cluster_op_type_name(uint32_t op_type) {
    switch (op_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV: return "move_objects";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        return "build_clusters_bottom_level";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
        return "build_triangle_cluster";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
        return "build_triangle_cluster_template";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
        return "instantiate_triangle_cluster";
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        return "get_cluster_template_indices";
    }
    return "other";
}

namespace {

// One line for a finding or a note: both name their rule, place, op and message alike.
std::string rule_line(const std::string& rule, const ReplayLocation& where, int64_t op_index,
                      const std::string& message) {
    std::string s = rule + ": " + finding_place_text(where);
    if (op_index >= 0) s += ", op " + std::to_string(op_index);
    return s + ": " + message;
}

}  // namespace

std::string ReplayFinding::format() const { return rule_line(rule, where, op_index, message); }

std::string ReplayNote::format() const { return rule_line(rule, where, op_index, message); }

namespace {

// The limits of the replay, apart from the findings: they do not change the exit status.
std::string notes_text(const ReplayReport& r) {
    if (r.notes.empty() && r.not_replayed.empty() && !r.notes_over_cap) return "";
    std::string s = "\nNotes (limits of this replay, not findings):\n";
    for (const ReplayNote& n : r.notes) s += "  " + n.format() + "\n";
    if (r.notes_over_cap) s += "  (" + std::to_string(r.notes_over_cap) + " more notes not kept)\n";
    for (const NotReplayed& n : r.not_replayed)
        s += "  not replayed: " + finding_place_text(n.where) + ": " + n.reason + "\n";
    return s;
}

// The per-command size tables: cluster builds, then NV objects.
void append_size_tables(const ReplayReport& r, std::string& s) {
    char line[384];
    if (!r.sizes.empty()) {
        s += "  sizes, capture vs engine:\n";
        std::snprintf(line, sizeof line, "  %-26s %-31s %6s %8s %14s %14s %6s %12s %12s %s\n",
                      "command", "op type", "ops", "compared", "captured bytes", "engine bytes",
                      "equal", "scratch", "dst span", "spans");
        s += line;
        for (const SizeComparison& c : r.sizes) {
            const std::string where = short_where(c.where);
            std::snprintf(line, sizeof line,
                          "  %-26s %-31s %6u %8u %14" PRIu64 " %14" PRIu64 " %6u %12" PRIu64
                          " %12" PRIu64 " %s\n",
                          where.c_str(), cluster_op_type_name(c.op_type), c.ops, c.ops_compared,
                          c.captured_bytes, c.engine_bytes, c.sizes_equal, c.scratch_span,
                          c.destination_span,
                          c.spans_queried ? "queried" : "assumed (engine worst case)");
            s += line;
        }
    }
    if (r.rows_over_cap)
        s += "  (" + std::to_string(r.rows_over_cap) +
             " more per-command rows not kept: ReplayOptions::max_command_rows)\n";
    if (!r.nv_sizes.empty()) {
        s += "  NV objects, driver vs engine bytes:\n";
        std::snprintf(line, sizeof line, "  %-26s %-6s %10s %14s %14s %14s\n", "command", "level",
                      "primitives", "driver object", "engine object", "engine used");
        s += line;
        for (const NvSizeComparison& c : r.nv_sizes) {
            const std::string where = short_where(c.where);
            std::snprintf(line, sizeof line,
                          "  %-26s %-6s %10" PRIu64 " %14s %14" PRIu64 " %14" PRIu64 "\n",
                          where.c_str(), c.top_level ? "top" : "bottom", c.primitives,
                          c.driver_object ? std::to_string(c.driver_object).c_str() : "-",
                          c.engine_object, c.engine_bytes);
            s += line;
        }
    }
}

void append_ray_checks(const ReplayReport& r, std::string& s) {
    char line[384];
    for (const RayCheckResult& c : r.ray_checks) {
        if (!c.checked) {
            s += "  ray check '" + c.label + "' on " + hex(c.acceleration_structure) +
                 ": not checked: " + c.why_not + "\n";
            continue;
        }
        // Labels say how the rays were traced and can be long: the first words name the check.
        const std::string label =
            c.label.size() > 40 ? std::string(traces::utf8_prefix(c.label, 37)) + "..." : c.label;
        std::snprintf(line, sizeof line,
                      "  ray check '%s' on %s: %" PRIu64 " rays, agree %" PRIu64 " (%" PRIu64
                      " hits, %" PRIu64 " misses; %" PRIu64
                      " of the hits within float32 error only), tie %" PRIu64 ", edge %" PRIu64
                      ", disagree %" PRIu64 " (far/tiny %" PRIu64 ", NaN/degenerate %" PRIu64
                      ", unexplained %" PRIu64 "); %s traversal\n",
                      label.c_str(), hex(c.acceleration_structure).c_str(), c.rays,
                      c.agree_hit + c.agree_miss, c.agree_hit, c.agree_miss, c.float_precision,
                      c.tie, c.edge, c.disagree, c.disagree_far_tiny, c.disagree_degenerate,
                      c.disagree_unexplained, c.traversal.c_str());
        s += line;
    }
}

void append_counts(const ReplayReport& r, std::string& s) {
    char line[384];
    const ReplayCounts& n = r.counts;
    std::snprintf(line, sizeof line,
                  "  records %" PRIu64 ", submissions %" PRIu64 ", commands replayed %" PRIu64
                  " (skipped %" PRIu64 "), cluster commands %" PRIu64 " (%" PRIu64
                  " ops), copies/fills/updates %" PRIu64 "\n",
                  n.records, n.submissions, n.commands, n.skipped_commands, n.cluster_commands,
                  n.cluster_ops, n.copies);
    s += line;
    std::snprintf(line, sizeof line,
                  "  snapshots laid in %" PRIu64 " (%" PRIu64 " bytes, %" PRIu64
                  " outside memory), outputs compared %" PRIu64 " (%" PRIu64
                  " bytes), addresses translated %" PRIu64 ", accesses checked %" PRIu64
                  ", memory image peak %" PRIu64 " bytes\n",
                  n.snapshots_applied, n.snapshot_bytes, n.snapshots_outside_memory,
                  n.outputs_compared, n.output_bytes_compared, n.addresses_translated, n.accesses,
                  n.peak_image_bytes);
    s += line;
    std::snprintf(line, sizeof line,
                  "  presents %" PRIu64 ", acquires %" PRIu64
                  ", semaphore waits with no signal in the trace %" PRIu64 "\n",
                  n.presents, n.acquires, n.unsatisfied_semaphore_waits);
    s += line;
    if (n.driver_bvh_ranges) {
        std::snprintf(line, sizeof line,
                      "  driver BVHs (traceable cluster BLASes) %" PRIu64
                      ", their bytes in later snapshots kept as the engine's %" PRIu64 "\n",
                      n.driver_bvh_ranges, n.driver_bvh_bytes_kept);
        s += line;
    }
    s += "  not replayed yet: " + std::to_string(r.not_replayed.size()) + " command(s)" +
         (r.hazards_checked ? "" : "; hazards not checked (--no-hazards)") +
         (r.verified ? "" : "; outputs not verified (--no-verify)") + "\n";
    if (const uint64_t notes = r.notes.size() + r.notes_over_cap)
        s += "  notes: " + std::to_string(notes) +
             " limit(s) of this replay (not findings; listed under Notes)\n";
}

// The last line: clean, or the findings counted by rule.
void append_result(const ReplayReport& r, std::string& s) {
    std::map<std::string, uint64_t> by_rule;
    for (const ReplayFinding& f : r.findings) ++by_rule[f.rule];
    for (const HazardReport& h : r.hazards) ++by_rule[hazard_rule_name(h)];
    if (by_rule.empty() && r.trace_damage.empty()) {
        s += "  result: clean\n";
    } else {
        s += "  result: " +
             std::to_string(r.findings.size() + r.hazards.size() + r.trace_damage.size()) +
             " finding(s)\n";
        for (const auto& [rule, count] : by_rule)
            s += "    " + std::to_string(count) + "  " + rule + "\n";
    }
}

}  // namespace

std::string format_text(const ReplayReport& r) {
    std::string s;
    for (const std::string& d : r.trace_damage) s += "CLASTRACE-trace-damaged: " + d + "\n";
    for (const ReplayFinding& f : r.findings) s += f.format() + "\n";
    for (const HazardReport& h : r.hazards) s += h.format() + "\n";
    if (r.findings_over_cap)
        s += "(" + std::to_string(r.findings_over_cap) + " more findings not kept)\n";
    if (r.hazards_over_cap)
        s += "(" + std::to_string(r.hazards_over_cap) + " more hazards not kept)\n";
    s += notes_text(r);

    s += "\nreplay of " + r.trace + " (" +
         (r.device.empty() ? std::string("unknown device") : r.device) +
         (r.engine_trace ? ", made by clastrace's engine: outputs compared byte for byte"
                         : ", captured on a driver: sizes compared side by side") +
         ")\n";
    append_size_tables(r, s);
    append_ray_checks(r, s);
    append_counts(r, s);
    append_result(r, s);
    return s;
}

namespace {

nlohmann::json row_json(const ReplayFinding& f) {
    return {{"rule", f.rule},
            {"source", finding_source_name(f.source)},
            {"where", where_json(f.where)},
            {"op_index", f.op_index},
            {"address", hex(f.address)},
            {"message", f.message}};
}

nlohmann::json row_json(const ReplayNote& n) {
    return {{"rule", n.rule},
            {"where", where_json(n.where)},
            {"op_index", n.op_index},
            {"address", hex(n.address)},
            {"message", n.message}};
}

nlohmann::json row_json(const SizeComparison& c) {
    nlohmann::json ops = nlohmann::json::array();
    for (const SizeComparison::OpSize& o : c.first_ops)
        ops.push_back({{"op", o.op}, {"captured", o.captured}, {"engine", o.engine}});
    return {{"where", where_json(c.where)},
            {"first_ops", ops},
            {"op_type", c.op_type},
            {"ops", c.ops},
            {"ops_compared", c.ops_compared},
            {"captured_bytes", c.captured_bytes},
            {"engine_bytes", c.engine_bytes},
            {"sizes_equal", c.sizes_equal},
            {"scratch_span", c.scratch_span},
            {"destination_span", c.destination_span},
            {"spans_queried", c.spans_queried}};
}

nlohmann::json row_json(const NvSizeComparison& c) {
    return {{"where", where_json(c.where)},
            {"handle", hex(c.handle)},
            {"level", c.top_level ? "top" : "bottom"},
            {"primitives", c.primitives},
            {"driver_object", c.driver_object},
            {"driver_build_scratch", c.driver_build_scratch},
            {"engine_object", c.engine_object},
            {"engine_build_scratch", c.engine_build_scratch},
            {"engine_bytes", c.engine_bytes}};
}

nlohmann::json row_json(const RayCheckResult& c) {
    return {{"label", c.label},
            {"acceleration_structure", hex(c.acceleration_structure)},
            {"after_submission", c.after_submission},
            {"checked", c.checked},
            {"why_not", c.why_not},
            {"rays", c.rays},
            {"agree_hit", c.agree_hit},
            {"agree_miss", c.agree_miss},
            {"agree_hit_float_precision", c.float_precision},
            {"tie", c.tie},
            {"edge", c.edge},
            {"disagree", c.disagree},
            {"disagree_far_tiny", c.disagree_far_tiny},
            {"disagree_degenerate", c.disagree_degenerate},
            {"disagree_unexplained", c.disagree_unexplained},
            {"traversal", c.traversal},
            {"max_rel_t", c.max_rel_t}};
}

nlohmann::json row_json(const NotReplayed& n) {
    return {{"where", where_json(n.where)}, {"reason", n.reason}};
}

template <typename Row>
nlohmann::json rows_json(const std::vector<Row>& rows) {
    nlohmann::json out = nlohmann::json::array();
    for (const Row& row : rows) out.push_back(row_json(row));
    return out;
}

nlohmann::json counts_json(const ReplayCounts& n) {
    return {{"records", n.records},
            {"submissions", n.submissions},
            {"commands", n.commands},
            {"skipped_commands", n.skipped_commands},
            {"cluster_commands", n.cluster_commands},
            {"cluster_ops", n.cluster_ops},
            {"copies", n.copies},
            {"barriers", n.barriers},
            {"accesses", n.accesses},
            {"snapshots_applied", n.snapshots_applied},
            {"snapshot_bytes", n.snapshot_bytes},
            {"snapshots_outside_memory", n.snapshots_outside_memory},
            {"driver_bvh_ranges", n.driver_bvh_ranges},
            {"driver_bvh_bytes_kept", n.driver_bvh_bytes_kept},
            {"outputs_compared", n.outputs_compared},
            {"output_bytes_compared", n.output_bytes_compared},
            {"addresses_translated", n.addresses_translated},
            {"peak_image_bytes", n.peak_image_bytes},
            {"nv_builds", n.nv_builds},
            {"deserializations", n.deserializations},
            {"handles_translated", n.handles_translated},
            {"presents", n.presents},
            {"acquires", n.acquires},
            {"unsatisfied_semaphore_waits", n.unsatisfied_semaphore_waits},
            {"khr_builds", n.khr_builds},
            {"khr_copies", n.khr_copies},
            {"query_answers", n.query_answers}};
}

}  // namespace

nlohmann::json to_json(const ReplayReport& r) {
    return {
        {"trace", r.trace},
        {"device", r.device},
        {"engine_trace", r.engine_trace},
        {"clean", r.clean()},
        {"hazards_checked", r.hazards_checked},
        {"outputs_verified", r.verified},
        {"findings", rows_json(r.findings)},
        {"findings_over_cap", r.findings_over_cap},
        {"hazards_merged", r.hazards_merged},
        {"hazards", to_json(r.hazards, r.hazards_over_cap)},
        {"notes", rows_json(r.notes)},
        {"notes_over_cap", r.notes_over_cap},
        {"sizes", rows_json(r.sizes)},
        {"not_replayed", rows_json(r.not_replayed)},
        {"rows_over_cap", r.rows_over_cap},
        {"nv_sizes", rows_json(r.nv_sizes)},
        {"ray_checks", rows_json(r.ray_checks)},
        {"trace_damage", r.trace_damage},
        {"counts", counts_json(r.counts)},
    };
}

}  // namespace clastrace::replay

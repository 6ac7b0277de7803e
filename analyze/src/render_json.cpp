// SPDX-License-Identifier: Apache-2.0
// JSON report. Field names are documented in docs/analyze.md; renaming or removing one bumps
// kReportSchemaVersion. Ratios whose denominator is zero are null.
#include <sstream>

#include <nlohmann/json.hpp>

#include "clastrace/analyze/render.h"
#include "format_util.h"

namespace clastrace::analyze {

namespace {

using Json = nlohmann::ordered_json;

Json opt(const std::optional<uint64_t>& v) { return v ? Json(*v) : Json(nullptr); }
Json opt(const std::optional<double>& v) { return v ? Json(*v) : Json(nullptr); }

Json signed_difference(uint64_t a, uint64_t b) {
    constexpr uint64_t kMax = static_cast<uint64_t>(INT64_MAX);
    if (a >= b) return Json(static_cast<int64_t>(std::min(a - b, kMax)));
    return Json(-static_cast<int64_t>(std::min(b - a, kMax)));
}

Json distribution(const ValueDistribution& d) {
    Json j;
    j["count"] = d.count();
    j["sum"] = d.sum();
    j["min"] = d.min();
    j["median"] = d.median();
    j["median_exact"] = d.median_exact();
    j["max"] = d.max();
    Json bins = Json::array();
    const auto& b = d.log2_bins();
    for (int i = 0; i < ValueDistribution::kLog2Bins; ++i) {
        if (b[i] == 0) continue;
        Json bin;
        bin["low"] = ValueDistribution::bin_low(i);
        bin["high"] =
            i == 0 ? uint64_t{0} : (i == 64 ? UINT64_MAX : ValueDistribution::bin_low(i + 1) - 1);
        bin["count"] = b[i];
        bins.push_back(bin);
    }
    j["log2_histogram"] = bins;
    return j;
}

Json command_row(const CommandRow& c) {
    Json j;
    j["ordinal"] = c.ordinal;
    j["submission"] = c.submission;
    j["command_buffer"] = c.command_buffer;
    j["index"] = c.index;
    j["name"] = c.name;
    j["op_type"] = op_type_name(c.op_type);
    j["op_mode"] = op_mode_name(c.op_mode);
    j["op_count"] = c.op_count;
    j["triangles"] = c.triangles;
    j["objects"] = c.objects;
    j["engine_bytes"] = c.engine_bytes;
    j["driver_bytes"] = c.driver_bytes;
    j["worst_case_bytes"] = opt(c.worst_case_bytes);
    j["implicit_allocated"] = c.implicit_allocated;
    j["scratch_allocated"] = c.scratch_allocated;
    j["scratch_required"] = opt(c.scratch_required);
    j["scratch_used"] = opt(c.scratch_used);
    j["gpu_ns"] = opt(c.gpu_ns);
    j["replay_ns"] = opt(c.replay_ns);
    j["hazards"] = c.hazards;
    return j;
}

Json sizes(const AnalysisReport& r) {
    Json by = Json::array();
    for (const OpTypeSizes& s : r.by_op_type) {
        if (s.commands == 0 && s.objects == 0) continue;
        Json j;
        j["op_type"] = op_type_name(s.op_type);
        j["commands"] = s.commands;
        j["ops"] = s.ops;
        j["objects"] = s.objects;
        j["triangles"] = s.triangles;
        j["vertices"] = s.vertices;
        j["engine_bytes"] = distribution(s.engine_bytes);
        j["bytes_per_triangle"] = opt(fmtu::ratio(s.engine_bytes.sum(), s.triangles));
        j["bytes_per_vertex"] = opt(fmtu::ratio(s.engine_bytes.sum(), s.vertices));
        j["driver_bytes"] =
            s.objects_with_driver_bytes ? distribution(s.driver_bytes) : Json(nullptr);
        j["engine_bytes_of_driver_objects"] = s.engine_bytes_of_driver_objects;
        Json q;
        q["commands_with_query"] = s.commands_with_query;
        q["worst_case_bytes"] = s.worst_case_bytes;
        q["actual_bytes"] = s.actual_bytes_of_queried;
        q["slack_bytes"] = signed_difference(s.worst_case_bytes, s.actual_bytes_of_queried);
        q["slack_ratio"] = s.worst_case_bytes >= s.actual_bytes_of_queried
                               ? opt(fmtu::ratio(s.worst_case_bytes - s.actual_bytes_of_queried,
                                                 s.worst_case_bytes))
                               : Json(nullptr);
        j["build_sizes"] = q;
        j["implicit_data"] = {{"allocated", s.implicit_allocated}, {"used", s.implicit_used}};
        j["scratch"] = {{"allocated", s.scratch_allocated},
                        {"required", s.scratch_required},
                        {"used", s.scratch_used}};
        by.push_back(j);
    }
    Json trunc = Json::array();
    for (const TruncationRow& t : r.truncation) {
        Json j;
        j["truncate_bits"] = t.truncate_bits;
        j["objects"] = t.objects;
        j["triangles"] = t.triangles;
        j["engine_bytes"] = t.engine_bytes;
        j["bytes_per_triangle"] = opt(fmtu::ratio(t.engine_bytes, t.triangles));
        j["objects_with_untruncated"] = t.objects_with_untruncated;
        j["engine_bytes_of_those"] = t.engine_bytes_of_those;
        j["untruncated_bytes"] = t.untruncated_bytes;
        j["saved_ratio"] = t.untruncated_bytes >= t.engine_bytes_of_those
                               ? opt(fmtu::ratio(t.untruncated_bytes - t.engine_bytes_of_those,
                                                 t.untruncated_bytes))
                               : Json(nullptr);
        trunc.push_back(j);
    }
    Json out;
    out["by_op_type"] = by;
    out["truncation"] = trunc;
    if (r.trace_bytes) {
        const TraceBytes& b = *r.trace_bytes;
        out["trace_bytes"] = {{"raw", b.raw},
                              {"deduplicated", b.deduplicated},
                              {"compressed", b.compressed},
                              {"dedup_ratio", opt(fmtu::ratio(b.raw, b.deduplicated))},
                              {"compression_ratio", opt(fmtu::ratio(b.raw, b.compressed))}};
    } else {
        out["trace_bytes"] = nullptr;
    }
    return out;
}

Json overlap(const AnalysisReport& r) {
    Json regions = Json::array();
    for (const RegionRow& g : r.region_rows)
        regions.push_back({{"id", g.id},
                           {"label", g.label},
                           {"role", region_role_name(g.role)},
                           {"base", g.base},
                           {"size", g.size},
                           {"first_command", g.first_command},
                           {"last_command", g.last_command},
                           {"uses", g.uses},
                           {"written", g.written}});
    Json pairs = Json::array();
    for (const OverlapRow& o : r.overlaps)
        pairs.push_back({{"older_region", o.older_region},
                         {"older_label", o.older_label},
                         {"older_role", region_role_name(o.older_role)},
                         {"older_command", o.older_command},
                         {"newer_region", o.newer_region},
                         {"newer_label", o.newer_label},
                         {"newer_role", region_role_name(o.newer_role)},
                         {"newer_command", o.newer_command},
                         {"base", o.base},
                         {"size", o.size},
                         {"events", o.events},
                         {"kind", overlap_kind_name(o.kind)},
                         {"hazard", o.hazard},
                         {"hazard_class", o.hazard ? Json(o.hazard_class) : Json(nullptr)},
                         {"hazard_index", opt(o.hazard_index)}});
    Json summary = Json::array();
    for (const OverlapSummaryRow& s : r.overlap_summary)
        summary.push_back({{"older_role", region_role_name(s.older_role)},
                           {"newer_role", region_role_name(s.newer_role)},
                           {"kind", overlap_kind_name(s.kind)},
                           {"hazard", s.hazard},
                           {"events", s.events},
                           {"bytes", s.bytes}});
    Json j;
    j["regions_tracked"] = r.regions;
    j["region_uses"] = r.region_uses;
    j["region_uses_not_tracked"] = r.region_uses_not_tracked;
    j["events"] = r.overlap_events;
    j["hazard_events"] = r.overlap_hazard_events;
    j["summary"] = summary;
    j["pairs"] = pairs;
    j["events_not_listed"] = r.overlap_events_not_listed;
    j["regions"] = regions;
    return j;
}

Json hazards(const AnalysisReport& r) {
    Json listed = Json::array();
    for (const HazardRow& h : r.hazards)
        listed.push_back({{"index", h.index},
                          {"class", h.hazard.hazard_class},
                          {"first_command", h.hazard.first_command},
                          {"second_command", h.hazard.second_command},
                          {"base", h.hazard.base},
                          {"size", h.hazard.size},
                          {"message", h.hazard.message},
                          {"matched_overlap_events", h.matched_overlaps}});
    return {{"total", r.hazards_total}, {"not_listed", r.hazards_not_listed}, {"listed", listed}};
}

Json timing(const AnalysisReport& r) {
    Json by = Json::array();
    for (const OpTypeSizes& s : r.by_op_type) {
        if (s.commands == 0) continue;
        auto mtris = [](uint64_t tris, uint64_t ns) {
            auto v = fmtu::per_second(tris, ns);
            return v ? Json(*v / 1e6) : Json(nullptr);
        };
        by.push_back({{"op_type", op_type_name(s.op_type)},
                      {"replay_ns", s.replay_ns},
                      {"replay_ops", s.replay_ops},
                      {"replay_triangles", s.replay_triangles},
                      {"replay_ops_per_second", opt(fmtu::per_second(s.replay_ops, s.replay_ns))},
                      {"replay_mtris_per_second", mtris(s.replay_triangles, s.replay_ns)},
                      {"gpu_commands", s.gpu_commands},
                      {"gpu_ns", s.gpu_ns},
                      {"gpu_ops", s.gpu_ops},
                      {"gpu_triangles", s.gpu_triangles},
                      {"gpu_ops_per_second", opt(fmtu::per_second(s.gpu_ops, s.gpu_ns))},
                      {"gpu_mtris_per_second", mtris(s.gpu_triangles, s.gpu_ns)}});
    }
    Json top_gpu = Json::array(), top_replay = Json::array();
    for (const CommandRow& c : r.top_by_gpu) top_gpu.push_back(command_row(c));
    for (const CommandRow& c : r.top_by_replay) top_replay.push_back(command_row(c));
    Json timeline = Json::array();
    for (const TimelineBucket& b : r.timeline)
        timeline.push_back({{"first_ordinal", b.first_ordinal},
                            {"last_ordinal", b.last_ordinal},
                            {"commands", b.commands},
                            {"ops", b.ops},
                            {"triangles", b.triangles},
                            {"replay_ns", b.replay_ns},
                            {"gpu_ns", b.gpu_ns},
                            {"gpu_commands", b.gpu_commands}});
    Json clock = nullptr;
    if (r.gpu_clock) {
        const GpuClock& c = *r.gpu_clock;
        Json calibration = nullptr;
        if (c.calibration_ticks && c.calibration_host_ns)
            calibration = {{"gpu_ticks", *c.calibration_ticks},
                           {"host_ns", *c.calibration_host_ns},
                           {"max_deviation_ns", opt(c.calibration_max_deviation_ns)}};
        clock = {{"timestamp_period_ns", c.timestamp_period_ns},
                 {"period_known", c.period_known},
                 {"calibration", calibration}};
    }
    Json spans = Json::array();
    for (const GpuSpanRow& g : r.gpu_spans)
        spans.push_back({{"first_ordinal", g.span.first_ordinal},
                         {"last_ordinal", g.span.last_ordinal},
                         {"commands", g.span.commands},
                         {"ops", g.span.ops},
                         {"triangles", g.span.triangles},
                         {"start_ticks", g.span.start_ticks},
                         {"start_ns", g.start_ns},
                         {"host_start_ns", opt(g.host_start_ns)},
                         {"gpu_ns", g.span.gpu_ns}});
    auto mtris_all = [](uint64_t tris, uint64_t ns) {
        auto v = fmtu::per_second(tris, ns);
        return v ? Json(*v / 1e6) : Json(nullptr);
    };
    Json gpu_spans = {{"total", r.gpu_spans_total},
                      {"gpu_ns", r.gpu_spans_ns},
                      {"ops", r.gpu_spans_ops},
                      {"triangles", r.gpu_spans_triangles},
                      {"ops_per_second", opt(fmtu::per_second(r.gpu_spans_ops, r.gpu_spans_ns))},
                      {"mtris_per_second", mtris_all(r.gpu_spans_triangles, r.gpu_spans_ns)},
                      {"listed", spans}};
    return {{"gpu_timing_present", r.gpu_timing_present},
            {"replay_timing_present", r.replay_timing_present},
            {"gpu_clock", clock},
            {"gpu_spans", gpu_spans},
            {"by_op_type", by},
            {"top_by_gpu", top_gpu},
            {"top_by_replay", top_replay},
            {"timeline", timeline}};
}

}  // namespace

void render_json(const AnalysisReport& r, std::ostream& out) {
    Json j;
    j["schema_version"] = r.schema_version;
    j["tool"] = "clastrace analyze";
    j["trace"] = r.trace_name;
    j["totals"] = {{"commands", r.commands},
                   {"submissions", r.submissions},
                   {"ops", r.ops},
                   {"objects", r.objects},
                   {"triangles", r.triangles},
                   {"largest_submission",
                    {{"submission", r.largest_submission},
                     {"commands", r.largest_submission_commands},
                     {"ops", r.largest_submission_ops}}}};
    j["sizes"] = sizes(r);
    Json commands;
    commands["listed"] = Json::array();
    for (const CommandRow& c : r.commands_listed) commands["listed"].push_back(command_row(c));
    commands["not_listed"] = r.commands_not_listed;
    Json kinds = Json::array();
    for (const CommandKindRow& k : r.command_kinds)
        kinds.push_back({{"name", k.name},
                         {"commands", k.commands},
                         {"ops", k.ops},
                         {"triangles", k.triangles},
                         {"objects", k.objects},
                         {"engine_bytes", k.engine_bytes},
                         {"driver_bytes", k.driver_bytes},
                         {"replay_ns", k.replay_ns},
                         {"replay_commands", k.replay_commands},
                         {"gpu_ns", k.gpu_ns},
                         {"gpu_commands", k.gpu_commands},
                         {"hazards", k.hazards}});
    commands["kinds"] = kinds;
    commands["kinds_not_listed"] = r.command_kinds_not_listed;
    j["commands"] = commands;
    j["overlap"] = overlap(r);
    j["hazards"] = hazards(r);
    j["timing"] = timing(r);
    j["notes"] = r.notes;
    // Names and labels come from traces and file names and need not be UTF-8: each ill-formed
    // sequence becomes U+FFFD (traces::valid_utf8's rule) rather than throwing.
    out << j.dump(2, ' ', false, Json::error_handler_t::replace) << '\n';
}

std::string render_json(const AnalysisReport& r) {
    std::ostringstream s;
    render_json(r, s);
    return s.str();
}

}  // namespace clastrace::analyze

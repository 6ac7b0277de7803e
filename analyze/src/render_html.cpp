// SPDX-License-Identifier: Apache-2.0
// One self-contained HTML page: inline CSS and SVG, no script, no reference outside the file.
#include <set>
#include <sstream>

#include "clastrace/analyze/render.h"
#include "format_util.h"
#include "markup.h"
#include "svg_charts.h"

namespace clastrace::analyze {

namespace {

using fmt::format;

constexpr const char* kStyle = R"css(
body { font: 14px/1.4 system-ui, sans-serif; margin: 24px; color: #222; max-width: 1240px; }
h1 { font-size: 22px; margin: 0 0 4px; } h2 { font-size: 18px; margin: 28px 0 8px; border-bottom: 1px solid #ccc; }
h3 { font-size: 15px; margin: 18px 0 6px; }
table { border-collapse: collapse; margin: 6px 0 12px; }
th, td { border: 1px solid #ddd; padding: 2px 8px; } th { background: #f4f4f4; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr:target { background: #fff3b0; }
.hazard-row td { background: #fdecea; }
.chart { display: block; margin: 6px 0; background: #fcfcfc; border: 1px solid #e3e3e3; }
.chart text { font-size: 11px; fill: #444; } .chart .axis-title { font-size: 12px; fill: #222; }
.chart .axis-line { stroke: #bbb; stroke-width: 1; } .chart .gap { stroke: #999; stroke-dasharray: 2 3; }
.chart .region-label { font-size: 10px; fill: #111; pointer-events: none; }
.region { stroke: #fff; stroke-width: 0.5; fill-opacity: 0.85; }
.role-buffer { stroke: #999; stroke-dasharray: 3 2; fill-opacity: 0.6; }
.overlap { fill: none; stroke-width: 2; }
.overlap.hazard { stroke: #d62728; stroke-width: 3; fill: #d62728; fill-opacity: 0.25; }
.overlap.aliasing { stroke: #ff7f0e; fill: #ff7f0e; fill-opacity: 0.15; }
.overlap.reuse { stroke: #555; stroke-dasharray: 4 3; }
.bar { fill: #2e86c1; } .budget-whole { fill: #e5e8e8; stroke: #aab7b8; }
.budget-part.objects { fill: #2e86c1; } .budget-part.implicit { fill: #7fb3d5; }
.budget-part.scratch { fill: #f2a65a; } .budget-part.over { fill: #d62728; } .replay { fill: #5d6d7e; } .gpu { fill: #28b463; }
.legend span { display: inline-block; margin-right: 14px; } .swatch { display: inline-block; width: 12px;
  height: 12px; margin-right: 4px; vertical-align: -1px; border: 1px solid #999; }
.hists { display: flex; flex-wrap: wrap; gap: 16px; } .note { color: #666; }
)css";

constexpr std::size_t kMaxHtmlPairs = 300;

std::string num(uint64_t v) { return format("<td class=\"num\">{}</td>", v); }
std::string num_text(const std::string& v) {
    return format("<td class=\"num\">{}</td>", escape_markup(v));
}
std::string txt(const std::string& v) { return format("<td>{}</td>", escape_markup(v)); }
std::string opt_num(const std::optional<uint64_t>& v) { return v ? num(*v) : num_text("-"); }
std::string head(std::initializer_list<const char*> cols) {
    std::string s = "<tr>";
    for (const char* c : cols) s += format("<th>{}</th>", c);
    return s + "</tr>\n";
}
std::string cmd_link(uint64_t ordinal, const std::set<uint64_t>& listed) {
    if (!listed.count(ordinal)) return num(ordinal);
    return format("<td class=\"num\"><a href=\"#cmd-{0}\">{0}</a></td>", ordinal);
}

template <class F>
void for_each_used_op_type(const AnalysisReport& r, F f) {
    for (const OpTypeSizes& t : r.by_op_type)
        if (t.commands > 0 || t.objects > 0) f(t);
}

void sizes(const AnalysisReport& r, std::ostream& out) {
    out << "<h2 id=\"sizes\">Sizes</h2>\n<table id=\"sizes-table\">\n"
        << head({"op type", "commands", "ops", "objects", "triangles", "bytes", "min", "median",
                 "max", "bytes/triangle"});
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        const ValueDistribution& d = s.engine_bytes;
        out << format("<tr data-op-type=\"{}\">", op_type_name(s.op_type))
            << txt(op_type_name(s.op_type)) << num(s.commands) << num(s.ops) << num(s.objects)
            << num(s.triangles) << num(d.sum()) << num(d.min())
            << num_text(format("{}{}", d.median(), d.median_exact() ? "" : " (approx.)"))
            << num(d.max()) << num_text(fmtu::fixed(fmtu::ratio(d.sum(), s.triangles), 2))
            << "</tr>\n";
    });
    out << "</table>\n";

    bool any_driver = false;
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        any_driver |= s.objects_with_driver_bytes > 0;
    });
    if (!any_driver) {
        out << "<h3>Driver vs engine</h3>\n<p class=\"note\">The capture recorded no driver sizes "
               "(dstSizesArray).</p>\n";
    } else {
        out << "<h3>Driver vs engine</h3>\n<table id=\"driver-table\">\n"
            << head({"op type", "objects with driver size", "driver bytes", "engine bytes",
                     "driver/engine", "driver median"});
        for_each_used_op_type(r, [&](const OpTypeSizes& s) {
            if (!s.objects_with_driver_bytes) return;
            out << "<tr>" << txt(op_type_name(s.op_type)) << num(s.objects_with_driver_bytes)
                << num(s.driver_bytes.sum()) << num(s.engine_bytes_of_driver_objects)
                << num_text(fmtu::fixed(fmtu::ratio(s.driver_bytes.sum(),
                                                    s.engine_bytes_of_driver_objects),
                                        3))
                << num(s.driver_bytes.median()) << "</tr>\n";
        });
        out << "</table>\n";
    }

    out << "<h3>Worst case vs actual, allocated vs used</h3>\n<table id=\"build-sizes-table\">\n"
        << head({"op type", "commands with query", "worst case", "actual", "slack", "slack %",
                 "implicit allocated", "implicit used", "scratch allocated", "scratch required",
                 "scratch used"});
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        out << "<tr>" << txt(op_type_name(s.op_type)) << num(s.commands_with_query)
            << num(s.worst_case_bytes) << num(s.actual_bytes_of_queried)
            << num_text(fmtu::difference(s.worst_case_bytes, s.actual_bytes_of_queried))
            << num_text(
                   fmtu::percent(s.worst_case_bytes >= s.actual_bytes_of_queried
                                     ? fmtu::ratio(s.worst_case_bytes - s.actual_bytes_of_queried,
                                                   s.worst_case_bytes)
                                     : std::nullopt))
            << num(s.implicit_allocated) << num(s.implicit_used) << num(s.scratch_allocated)
            << num(s.scratch_required) << num(s.scratch_used) << "</tr>\n";
    });
    out << "</table>\n"
        << svg_size_budget(r) << "<h3>Object size histograms</h3>\n<div class=\"hists\">\n";
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        if (s.objects)
            out << "<figure>" << svg_size_histogram(s) << "<figcaption>" << op_type_name(s.op_type)
                << "</figcaption></figure>\n";
    });
    out << "</div>\n";

    if (!r.truncation.empty()) {
        out << "<h3>positionTruncateBitCount</h3>\n<table id=\"truncation-table\">\n"
            << head({"bits", "objects", "triangles", "bytes", "bytes/triangle", "untruncated bytes",
                     "saved"});
        for (const TruncationRow& t : r.truncation)
            out << "<tr>" << num(t.truncate_bits) << num(t.objects) << num(t.triangles)
                << num(t.engine_bytes)
                << num_text(fmtu::fixed(fmtu::ratio(t.engine_bytes, t.triangles), 2))
                << (t.objects_with_untruncated ? num(t.untruncated_bytes) : num_text("-"))
                << num_text(t.objects_with_untruncated &&
                                    t.untruncated_bytes >= t.engine_bytes_of_those
                                ? fmtu::percent(
                                      fmtu::ratio(t.untruncated_bytes - t.engine_bytes_of_those,
                                                  t.untruncated_bytes))
                                : "-")
                << "</tr>\n";
        out << "</table>\n" << svg_truncation(r);
    }
    if (r.trace_bytes) {
        const TraceBytes& b = *r.trace_bytes;
        out << "<h3>Trace bytes</h3>\n<table id=\"trace-bytes-table\">\n"
            << head({"raw", "deduplicated", "compressed", "raw/dedup", "raw/compressed"}) << "<tr>"
            << num(b.raw) << num(b.deduplicated) << num(b.compressed)
            << num_text(fmtu::fixed(fmtu::ratio(b.raw, b.deduplicated), 2))
            << num_text(fmtu::fixed(fmtu::ratio(b.raw, b.compressed), 2)) << "</tr>\n</table>\n";
    }
}

void memory(const AnalysisReport& r, const std::set<uint64_t>& listed, std::ostream& out) {
    out << "<h2 id=\"memory\">Memory map and overlap</h2>\n";
    out << format("<p>{} regions, {} uses. {} overlap events, {} of them hazards.{}</p>\n",
                  r.regions, r.region_uses, r.overlap_events, r.overlap_hazard_events,
                  r.region_uses_not_tracked
                      ? format(" {} uses past the tracking limit are counted but not drawn.",
                               r.region_uses_not_tracked)
                      : std::string());
    out << "<p class=\"legend\">";
    std::set<RegionRole> roles;
    for (const RegionRow& g : r.region_rows) roles.insert(g.role);
    for (RegionRole role : roles)
        out << format("<span><i class=\"swatch\" style=\"background:{}\"></i>{}</span>",
                      role_color(role), region_role_name(role));
    out << "<span><i class=\"swatch\" style=\"border:2px solid #d62728\"></i>hazard</span>"
           "<span><i class=\"swatch\" style=\"border:2px solid #ff7f0e\"></i>aliasing</span>"
           "<span><i class=\"swatch\" style=\"border:2px dashed #555\"></i>ordered "
           "reuse</span></p>\n";
    out << svg_memory_map(r);

    out << "<h3>Overlap summary</h3>\n<table id=\"overlap-summary\">\n"
        << head({"older role", "newer role", "kind", "verdict", "events", "bytes"});
    for (const OverlapSummaryRow& s : r.overlap_summary)
        out << (s.hazard ? "<tr class=\"hazard-row\">" : "<tr>")
            << txt(region_role_name(s.older_role)) << txt(region_role_name(s.newer_role))
            << txt(overlap_kind_name(s.kind)) << txt(s.hazard ? "hazard" : "safe") << num(s.events)
            << num(s.bytes) << "</tr>\n";
    out << "</table>\n<h3>Overlapping region pairs</h3>\n<table id=\"overlap-pairs\">\n"
        << head({"older region", "older role", "command", "newer region", "newer role", "command",
                 "address", "bytes", "kind", "verdict"});
    // Hazards first, then aliasing, then ordered reuse; each in the order found.
    std::vector<const OverlapRow*> rows;
    for (int rank = 0; rank < 3; ++rank)
        for (const OverlapRow& o : r.overlaps)
            if ((o.hazard ? 0 : o.kind == OverlapKind::kAliasing ? 1 : 2) == rank)
                rows.push_back(&o);
    if (rows.size() > kMaxHtmlPairs) rows.resize(kMaxHtmlPairs);
    for (const OverlapRow* op : rows) {
        const OverlapRow& o = *op;
        std::string verdict =
            o.hazard ? (o.hazard_index ? format("<a href=\"#hazard-{}\">hazard {}</a>",
                                                *o.hazard_index, escape_markup(o.hazard_class))
                                       : "hazard " + escape_markup(o.hazard_class))
                     : std::string("safe");
        out << (o.hazard ? "<tr class=\"hazard-row\">" : "<tr>") << txt(o.older_label)
            << txt(region_role_name(o.older_role)) << cmd_link(o.older_command, listed)
            << txt(o.newer_label) << txt(region_role_name(o.newer_role))
            << cmd_link(o.newer_command, listed) << num_text(fmtu::hex(o.base)) << num(o.size)
            << txt(overlap_kind_name(o.kind)) << "<td>" << verdict << "</td></tr>\n";
    }
    out << "</table>\n";
    if (r.overlaps.size() > kMaxHtmlPairs)
        out << format("<p class=\"note\">{} more pairs (ordered reuse) in the JSON report.</p>\n",
                      r.overlaps.size() - kMaxHtmlPairs);
    if (r.overlap_events_not_listed)
        out << format(
            "<p class=\"note\">{} more overlap events belong to pairs past the listing "
            "limit.</p>\n",
            r.overlap_events_not_listed);
}

void hazards(const AnalysisReport& r, const std::set<uint64_t>& listed, std::ostream& out) {
    out << format("<h2 id=\"hazards\">Hazards ({})</h2>\n<table id=\"hazard-table\">\n",
                  r.hazards_total)
        << head({"#", "class", "first command", "second command", "address", "bytes",
                 "overlap events", "message"});
    for (const HazardRow& h : r.hazards)
        out << format("<tr id=\"hazard-{}\" class=\"hazard-row\">", h.index) << num(h.index)
            << txt(h.hazard.hazard_class) << cmd_link(h.hazard.first_command, listed)
            << cmd_link(h.hazard.second_command, listed) << num_text(fmtu::hex(h.hazard.base))
            << num(h.hazard.size) << num(h.matched_overlaps) << txt(h.hazard.message) << "</tr>\n";
    out << "</table>\n";
    if (r.hazards_not_listed)
        out << format("<p class=\"note\">{} more hazards not listed.</p>\n", r.hazards_not_listed);
}

void timing(const AnalysisReport& r, const std::set<uint64_t>& listed, std::ostream& out) {
    out << "<h2 id=\"timing\">Timing</h2>\n<p class=\"legend\">"
           "<span><i class=\"swatch\" style=\"background:#5d6d7e\"></i>replay engine</span>"
           "<span><i class=\"swatch\" style=\"background:#28b463\"></i>GPU timestamps</span></p>\n"
        << svg_timeline(r);
    out << "<table id=\"timing-table\">\n"
        << head({"op type", "replay ms", "replay ops/s", "replay Mtris/s", "GPU commands", "GPU ms",
                 "GPU ops/s", "GPU Mtris/s"});
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        auto mtris = [](uint64_t tris, uint64_t ns) {
            auto v = fmtu::per_second(tris, ns);
            return fmtu::fixed(v ? std::optional<double>(*v / 1e6) : std::nullopt, 3);
        };
        out << "<tr>" << txt(op_type_name(s.op_type)) << num_text(fmtu::ms(s.replay_ns))
            << num_text(fmtu::fixed(fmtu::per_second(s.replay_ops, s.replay_ns), 0))
            << num_text(mtris(s.replay_triangles, s.replay_ns)) << num(s.gpu_commands)
            << num_text(fmtu::ms(s.gpu_ns))
            << num_text(fmtu::fixed(fmtu::per_second(s.gpu_ops, s.gpu_ns), 0))
            << num_text(mtris(s.gpu_triangles, s.gpu_ns)) << "</tr>\n";
    });
    out << "</table>\n";
    auto top = [&](const std::vector<CommandRow>& rows, const char* id, const char* clock) {
        if (rows.empty()) return;
        out << format("<h3>Most expensive commands by {} time</h3>\n<table id=\"{}\">\n", clock, id)
            << head({"command", "name", "op type", "ops", "triangles", "GPU ns", "replay ns",
                     "bytes"});
        for (const CommandRow& c : rows)
            out << "<tr>" << cmd_link(c.ordinal, listed) << txt(c.name)
                << txt(op_type_name(c.op_type)) << num(c.op_count) << num(c.triangles)
                << opt_num(c.gpu_ns) << opt_num(c.replay_ns) << num(c.engine_bytes) << "</tr>\n";
        out << "</table>\n";
    };
    top(r.top_by_gpu, "top-gpu", "GPU");
    top(r.top_by_replay, "top-replay", "replay");

    out << format("<h3 id=\"gpu\">GPU timestamp spans ({})</h3>\n", r.gpu_spans_total)
        << svg_gpu_spans(r);
    if (r.gpu_spans.empty()) return;
    const GpuClock clock = r.gpu_clock.value_or(GpuClock{});
    out << format(
               "<p class=\"note\">Timestamp period {} ns{}{}. {} ms over all spans: {} "
               "ops/s.</p>\n",
               clock.timestamp_period_ns, clock.period_known ? "" : " (assumed)",
               clock.calibration_ticks
                   ? format("; device tick {} = host {} ns", *clock.calibration_ticks,
                            clock.calibration_host_ns.value_or(0))
                   : std::string(),
               fmtu::ms(r.gpu_spans_ns),
               fmtu::fixed(fmtu::per_second(r.gpu_spans_ops, r.gpu_spans_ns), 0))
        << "<table id=\"gpu-spans\">\n"
        << head({"first command", "last command", "commands", "ops", "triangles", "start ns",
                 "host start ns", "GPU ns", "ops/s"});
    for (const GpuSpanRow& g : r.gpu_spans)
        out << "<tr>" << cmd_link(g.span.first_ordinal, listed)
            << cmd_link(g.span.last_ordinal, listed) << num(g.span.commands) << num(g.span.ops)
            << num(g.span.triangles) << num(g.start_ns) << opt_num(g.host_start_ns)
            << num(g.span.gpu_ns)
            << num_text(fmtu::fixed(fmtu::per_second(g.span.ops, g.span.gpu_ns), 0)) << "</tr>\n";
    out << "</table>\n";
}

void commands(const AnalysisReport& r, std::ostream& out) {
    out << "<h2 id=\"commands\">Commands</h2>\n<table id=\"command-kinds\">\n"
        << head({"command", "commands", "ops", "triangles", "objects", "engine bytes",
                 "driver bytes", "replay ns", "GPU ns", "hazards"});
    for (const CommandKindRow& k : r.command_kinds)
        out << format("<tr data-name=\"{}\">", escape_markup(k.name)) << txt(k.name)
            << num(k.commands) << num(k.ops) << num(k.triangles) << num(k.objects)
            << num(k.engine_bytes) << num(k.driver_bytes)
            << (k.replay_commands ? num(k.replay_ns) : num_text("-"))
            << (k.gpu_commands ? num(k.gpu_ns) : num_text("-")) << num(k.hazards) << "</tr>\n";
    out << "</table>\n<table id=\"command-table\">\n"
        << head({"command", "submission", "cb", "index", "name", "op type", "mode", "ops",
                 "triangles", "objects", "bytes", "driver bytes", "worst case",
                 "implicit allocated", "scratch allocated", "GPU ns", "replay ns", "hazards"});
    for (const CommandRow& c : r.commands_listed)
        out << format("<tr id=\"cmd-{}\"{}>", c.ordinal, c.hazards ? " class=\"hazard-row\"" : "")
            << num(c.ordinal) << num(c.submission) << num(c.command_buffer) << num(c.index)
            << txt(c.name) << txt(op_type_name(c.op_type)) << txt(op_mode_name(c.op_mode))
            << num(c.op_count) << num(c.triangles) << num(c.objects) << num(c.engine_bytes)
            << num(c.driver_bytes) << opt_num(c.worst_case_bytes) << num(c.implicit_allocated)
            << num(c.scratch_allocated) << opt_num(c.gpu_ns) << opt_num(c.replay_ns)
            << num(c.hazards) << "</tr>\n";
    out << "</table>\n";
    if (r.commands_not_listed)
        out << format(
            "<p class=\"note\">{} more commands not listed (the timeline and totals include "
            "them).</p>\n",
            r.commands_not_listed);
}

}  // namespace

void render_html(const AnalysisReport& r, std::ostream& out) {
    const std::string name = escape_markup(r.trace_name.empty() ? "(unnamed trace)" : r.trace_name);
    std::set<uint64_t> listed;
    for (const CommandRow& c : r.commands_listed) listed.insert(c.ordinal);
    out << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        << format("<meta name=\"generator\" content=\"clastrace analyze, report schema {}\">\n",
                  r.schema_version)
        << "<title>clastrace analyze: " << name << "</title>\n<style>" << kStyle
        << "</style>\n</head>\n<body>\n"
        << "<h1>clastrace analyze: " << name << "</h1>\n"
        << "<nav><a href=\"#sizes\">Sizes</a> · <a href=\"#memory\">Memory map</a> · <a "
           "href=\"#hazards\">Hazards</a> · "
           "<a href=\"#timing\">Timing</a> · <a href=\"#gpu\">GPU spans</a> · <a "
           "href=\"#commands\">Commands</a></nav>\n"
        << "<table id=\"totals\">\n"
        << head({"commands", "submissions", "ops", "objects", "triangles", "regions",
                 "overlap events", "hazards"})
        << "<tr>" << num(r.commands) << num(r.submissions) << num(r.ops) << num(r.objects)
        << num(r.triangles) << num(r.regions) << num(r.overlap_events) << num(r.hazards_total)
        << "</tr>\n</table>\n"
        << format(
               "<p id=\"largest-submission\" data-submission=\"{0}\" data-commands=\"{1}\" "
               "data-ops=\"{2}\">"
               "Largest submission: #{0}, {1} commands, {2} ops.</p>\n",
               r.largest_submission, r.largest_submission_commands, r.largest_submission_ops);
    if (!r.notes.empty()) {
        out << "<ul id=\"notes\">\n";
        for (const std::string& n : r.notes) out << "<li>" << escape_markup(n) << "</li>\n";
        out << "</ul>\n";
    }
    sizes(r, out);
    memory(r, listed, out);
    hazards(r, listed, out);
    timing(r, listed, out);
    commands(r, out);
    out << "</body>\n</html>\n";
}

std::string render_html(const AnalysisReport& r) {
    std::ostringstream s;
    render_html(r, s);
    return s.str();
}

}  // namespace clastrace::analyze

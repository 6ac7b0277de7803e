// SPDX-License-Identifier: Apache-2.0
#include <sstream>

#include "clastrace/analyze/render.h"
#include "format_util.h"
#include "text_table.h"

namespace clastrace::analyze {

namespace {

using fmt::format;
using Align = TextTable::Align;
constexpr std::size_t kTextRows = 40;  // longer lists are in the JSON and HTML reports

std::string num(uint64_t v) { return format("{}", v); }
std::string opt_num(const std::optional<uint64_t>& v) { return v ? num(*v) : "-"; }
std::string opt_us(const std::optional<uint64_t>& ns) {
    return ns ? format("{:.1f}", static_cast<double>(*ns) / 1e3) : "-";
}

void heading(std::ostream& out, const std::string& title) {
    out << '\n' << title << '\n' << std::string(title.size(), '=') << '\n';
}

template <class F>
void for_each_used_op_type(const AnalysisReport& r, F f) {
    for (const OpTypeSizes& t : r.by_op_type)
        if (t.commands > 0 || t.objects > 0) f(t);
}

// Engine bytes per object, by op type.
void engine_sizes_table(const AnalysisReport& r, std::ostream& out) {
    TextTable t;
    t.column("op type", Align::kLeft)
        .column("cmds")
        .column("ops")
        .column("objects")
        .column("triangles");
    t.column("bytes").column("min").column("median").column("max").column("B/tri");
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        const ValueDistribution& d = s.engine_bytes;
        t.row({op_type_short(s.op_type), num(s.commands), num(s.ops), num(s.objects),
               num(s.triangles), num(d.sum()), num(d.min()),
               num(d.median()) + (d.median_exact() ? "" : "~"), num(d.max()),
               fmtu::fixed(fmtu::ratio(d.sum(), s.triangles), 2)});
    });
    t.print(out, kTextColumns);
}

// Captured driver sizes beside the engine's, where dstSizesArray was captured.
void driver_sizes_table(const AnalysisReport& r, std::ostream& out) {
    bool any_driver = false;
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        any_driver |= s.objects_with_driver_bytes > 0;
    });
    if (!any_driver) return;
    out << "\nDriver sizes (objects whose dstSizesArray was captured)\n";
    TextTable d;
    d.column("op type", Align::kLeft).column("objects").column("driver B").column("engine B");
    d.column("driver/engine").column("min").column("median").column("max");
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        if (s.objects_with_driver_bytes == 0) return;
        const ValueDistribution& v = s.driver_bytes;
        d.row({op_type_short(s.op_type), num(s.objects_with_driver_bytes), num(v.sum()),
               num(s.engine_bytes_of_driver_objects),
               fmtu::fixed(fmtu::ratio(v.sum(), s.engine_bytes_of_driver_objects), 3), num(v.min()),
               num(v.median()), num(v.max())});
    });
    d.print(out, kTextColumns);
}

// The build-sizes query's worst case against what the objects used.
void worst_case_table(const AnalysisReport& r, std::ostream& out) {
    out << "\nWorst case (build-sizes query) vs actual; dstImplicitData allocated vs used;\n"
           "scratch allocated vs required by the query\n";
    TextTable w;
    w.column("op type", Align::kLeft)
        .column("queried")
        .column("worst case")
        .column("actual")
        .column("slack");
    w.column("slack%").column("implicit").column("used").column("scratch").column("required");
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        w.row({op_type_short(s.op_type), num(s.commands_with_query), num(s.worst_case_bytes),
               num(s.actual_bytes_of_queried),
               fmtu::difference(s.worst_case_bytes, s.actual_bytes_of_queried),
               fmtu::percent(s.worst_case_bytes >= s.actual_bytes_of_queried
                                 ? fmtu::ratio(s.worst_case_bytes - s.actual_bytes_of_queried,
                                               s.worst_case_bytes)
                                 : std::nullopt),
               num(s.implicit_allocated), num(s.implicit_used), num(s.scratch_allocated),
               num(s.scratch_required)});
    });
    w.print(out, kTextColumns);
}

// One log2 histogram of object bytes per op type.
void object_bytes_histograms(const AnalysisReport& r, std::ostream& out) {
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        if (s.objects == 0) return;
        out << format("\nHistogram of object bytes, {} ({} objects)\n", op_type_short(s.op_type),
                      s.objects);
        const auto& bins = s.engine_bytes.log2_bins();
        uint64_t peak = 0;
        for (uint64_t b : bins) peak = std::max(peak, b);
        for (int b = 0; b < ValueDistribution::kLog2Bins; ++b) {
            if (bins[b] == 0) continue;
            std::string range =
                b == 0 ? "0"
                       : format("{}..{}", ValueDistribution::bin_low(b),
                                b == 64 ? UINT64_MAX : ValueDistribution::bin_low(b + 1) - 1);
            // 128-bit product: bins[b] * 30 overflows for hostile counts.
            auto bar = static_cast<std::size_t>(
                (static_cast<unsigned __int128>(bins[b]) * 30 + peak - 1) / peak);
            out << format("  {:>41} {:>10} {}\n", range, bins[b], std::string(bar, '#'));
        }
    });
}

// Sizes by positionTruncateBitCount.
void truncation_table(const AnalysisReport& r, std::ostream& out) {
    if (!r.truncation.empty()) {
        out << "\npositionTruncateBitCount and size (cluster and template objects)\n";
        TextTable t2;
        t2.column("bits").column("objects").column("triangles").column("bytes").column("B/tri");
        t2.column("untruncated B").column("saved");
        for (const TruncationRow& tr : r.truncation)
            t2.row({num(tr.truncate_bits), num(tr.objects), num(tr.triangles), num(tr.engine_bytes),
                    fmtu::fixed(fmtu::ratio(tr.engine_bytes, tr.triangles), 2),
                    tr.objects_with_untruncated ? num(tr.untruncated_bytes) : "-",
                    tr.objects_with_untruncated && tr.untruncated_bytes >= tr.engine_bytes_of_those
                        ? fmtu::percent(fmtu::ratio(tr.untruncated_bytes - tr.engine_bytes_of_those,
                                                    tr.untruncated_bytes))
                        : "-"});
        t2.print(out, kTextColumns);
    }
}

// The trace's raw, deduplicated and compressed bytes.
void trace_bytes_table(const AnalysisReport& r, std::ostream& out) {
    if (r.trace_bytes) {
        const TraceBytes& b = *r.trace_bytes;
        out << "\nTrace bytes\n";
        TextTable t3;
        t3.column("raw")
            .column("deduplicated")
            .column("compressed")
            .column("raw/dedup")
            .column("raw/compressed");
        t3.row({num(b.raw), num(b.deduplicated), num(b.compressed),
                fmtu::fixed(fmtu::ratio(b.raw, b.deduplicated), 2),
                fmtu::fixed(fmtu::ratio(b.raw, b.compressed), 2)});
        t3.print(out, kTextColumns);
    }
}

void sizes_section(const AnalysisReport& r, std::ostream& out) {
    heading(out, "Sizes by op type (engine bytes per object)");
    engine_sizes_table(r, out);
    driver_sizes_table(r, out);
    worst_case_table(r, out);
    object_bytes_histograms(r, out);
    truncation_table(r, out);
    trace_bytes_table(r, out);
}

void commands_section(const AnalysisReport& r, std::ostream& out) {
    heading(out, "Commands");
    if (!r.command_kinds.empty()) {
        out << "By kind (vkCmd...; driver B: captured sizes, and the object size the driver was "
               "asked for\n"
               "where replay does not rebuild the command's objects; replay and gpu in ms)\n";
        TextTable k;
        k.column("command", Align::kLeft)
            .column("cmds")
            .column("ops")
            .column("tris")
            .column("engine B");
        k.column("driver B").column("replay").column("gpu");
        for (const CommandKindRow& c : r.command_kinds) {
            const bool vk = c.name.rfind("vkCmd", 0) == 0;
            k.row({vk ? c.name.substr(5) : c.name, num(c.commands), num(c.ops), num(c.triangles),
                   num(c.engine_bytes), num(c.driver_bytes),
                   c.replay_commands ? fmtu::ms(c.replay_ns) : "-",
                   c.gpu_commands ? fmtu::ms(c.gpu_ns) : "-"});
        }
        k.print(out, kTextColumns);
        if (r.command_kinds_not_listed)
            out << format("({} commands of further kinds)\n", r.command_kinds_not_listed);
        out << '\n';
    }
    TextTable t;
    t.column("#")
        .column("sub")
        .column("op", Align::kLeft)
        .column("mode", Align::kLeft)
        .column("ops");
    t.column("objects")
        .column("bytes")
        .column("worst case")
        .column("implicit")
        .column("scratch")
        .column("haz");
    std::size_t shown = 0;
    for (const CommandRow& c : r.commands_listed) {
        if (shown++ == kTextRows) break;
        // Commands outside the cluster extension say what they are by name (vkCmd dropped).
        const std::string op = c.op_type != OpType::kOther     ? op_type_short(c.op_type)
                               : c.name.rfind("vkCmd", 0) == 0 ? c.name.substr(5)
                                                               : c.name;
        t.row({num(c.ordinal), num(c.submission), op, op_mode_name(c.op_mode), num(c.op_count),
               num(c.objects), num(c.engine_bytes), opt_num(c.worst_case_bytes),
               num(c.implicit_allocated), num(c.scratch_allocated), num(c.hazards)});
    }
    t.print(out, kTextColumns);
    uint64_t hidden = r.commands - std::min<uint64_t>(r.commands, kTextRows);
    if (hidden) out << format("({} more commands: see --json or --html)\n", hidden);
}

void overlap_section(const AnalysisReport& r, std::ostream& out) {
    heading(out, "Overlap");
    out << format("{} regions, {} uses; {} overlap events, {} of them hazards\n", r.regions,
                  r.region_uses, r.overlap_events, r.overlap_hazard_events);
    if (r.region_uses_not_tracked)
        out << format("({} region uses past the tracking limit: counted, not mapped)\n",
                      r.region_uses_not_tracked);
    if (!r.overlap_summary.empty()) {
        TextTable t;
        t.column("older role", Align::kLeft)
            .column("newer role", Align::kLeft)
            .column("kind", Align::kLeft);
        t.column("verdict", Align::kLeft).column("events").column("bytes");
        for (const OverlapSummaryRow& s : r.overlap_summary)
            t.row({region_role_name(s.older_role), region_role_name(s.newer_role),
                   overlap_kind_name(s.kind), s.hazard ? "HAZARD" : "safe", num(s.events),
                   num(s.bytes)});
        out << '\n';
        t.print(out, kTextColumns);
    }
    if (!r.overlaps.empty()) {
        out << "\nOverlapping region pairs\n";
        TextTable t;
        t.column("older", Align::kLeft)
            .column("role", Align::kLeft)
            .column("cmd")
            .column("newer", Align::kLeft);
        t.column("role", Align::kLeft)
            .column("cmd")
            .column("address")
            .column("bytes")
            .column("kind", Align::kLeft);
        t.column("verdict", Align::kLeft);
        std::size_t shown = 0;
        for (const OverlapRow& o : r.overlaps) {
            if (shown++ == kTextRows) break;
            std::string verdict = !o.hazard        ? "safe"
                                  : o.hazard_index ? format("HAZARD #{}", *o.hazard_index)
                                                   : "HAZARD";
            t.row({o.older_label, region_role_name(o.older_role), num(o.older_command),
                   o.newer_label, region_role_name(o.newer_role), num(o.newer_command),
                   fmtu::hex(o.base), num(o.size), overlap_kind_name(o.kind), verdict});
        }
        t.print(out, kTextColumns);
        if (r.overlaps.size() > kTextRows)
            out << format("({} more pairs in --json)\n", r.overlaps.size() - kTextRows);
    }
    if (r.hazards_total) {
        out << format("\nHazards ({})\n", r.hazards_total);
        TextTable t;
        t.column("#")
            .column("class", Align::kLeft)
            .column("first")
            .column("second")
            .column("address");
        t.column("bytes").column("overlaps").column("message", Align::kLeft);
        std::size_t shown = 0;
        for (const HazardRow& h : r.hazards) {
            if (shown++ == kTextRows) break;
            t.row({num(h.index), h.hazard.hazard_class, num(h.hazard.first_command),
                   num(h.hazard.second_command), fmtu::hex(h.hazard.base), num(h.hazard.size),
                   num(h.matched_overlaps), h.hazard.message});
        }
        t.print(out, kTextColumns);
    }
}

void timing_section(const AnalysisReport& r, std::ostream& out) {
    heading(out, "Timing");
    if (!r.gpu_timing_present && !r.replay_timing_present) {
        out << "No timing: the capture recorded no GPU timestamps and replay reported no engine "
               "time.\n";
        return;
    }
    TextTable t;
    t.column("op type", Align::kLeft).column("replay ms").column("ops/s").column("Mtris/s");
    t.column("gpu cmds").column("gpu ms").column("ops/s").column("Mtris/s");
    for_each_used_op_type(r, [&](const OpTypeSizes& s) {
        auto mtris = [](uint64_t tris, uint64_t ns) {
            auto v = fmtu::per_second(tris, ns);
            return fmtu::fixed(v ? std::optional<double>(*v / 1e6) : std::nullopt, 3);
        };
        t.row({op_type_short(s.op_type), fmtu::ms(s.replay_ns),
               fmtu::fixed(fmtu::per_second(s.replay_ops, s.replay_ns), 0),
               mtris(s.replay_triangles, s.replay_ns), num(s.gpu_commands), fmtu::ms(s.gpu_ns),
               fmtu::fixed(fmtu::per_second(s.gpu_ops, s.gpu_ns), 0),
               mtris(s.gpu_triangles, s.gpu_ns)});
    });
    t.print(out, kTextColumns);

    auto top = [&](const std::vector<CommandRow>& rows, const char* clock) {
        if (rows.empty()) return;
        out << format("\nTop {} commands by {} time\n", rows.size(), clock);
        TextTable t2;
        t2.column("#")
            .column("name", Align::kLeft)
            .column("op", Align::kLeft)
            .column("ops")
            .column("triangles");
        t2.column("gpu us").column("replay us").column("bytes");
        for (const CommandRow& c : rows)
            t2.row({num(c.ordinal), c.name, op_type_short(c.op_type), num(c.op_count),
                    num(c.triangles), opt_us(c.gpu_ns), opt_us(c.replay_ns), num(c.engine_bytes)});
        t2.print(out, kTextColumns);
    };
    top(r.top_by_gpu, "GPU");
    top(r.top_by_replay, "replay");

    if (r.gpu_spans_total) {
        const GpuClock clock = r.gpu_clock.value_or(GpuClock{});
        out << format("\nGPU timestamp spans: {} spans, {} ms, {} ops ({} ops/s), {} triangles\n",
                      r.gpu_spans_total, fmtu::ms(r.gpu_spans_ns), r.gpu_spans_ops,
                      fmtu::fixed(fmtu::per_second(r.gpu_spans_ops, r.gpu_spans_ns), 0),
                      r.gpu_spans_triangles);
        out << format("(timestamp period {} ns{}{})\n", clock.timestamp_period_ns,
                      clock.period_known ? "" : ", assumed",
                      clock.calibration_ticks
                          ? format("; calibrated: tick {} = host {} ns +- {} ns",
                                   *clock.calibration_ticks, clock.calibration_host_ns.value_or(0),
                                   clock.calibration_max_deviation_ns.value_or(0))
                          : std::string());
        TextTable s;
        s.column("commands")
            .column("cmds")
            .column("ops")
            .column("triangles")
            .column("start us")
            .column("host start ms");
        s.column("gpu us").column("ops/s");
        std::size_t shown = 0;
        for (const GpuSpanRow& g : r.gpu_spans) {
            if (shown++ == kTextRows) break;
            s.row({format("{}..{}", g.span.first_ordinal, g.span.last_ordinal),
                   num(g.span.commands), num(g.span.ops), num(g.span.triangles), opt_us(g.start_ns),
                   g.host_start_ns ? format("{:.3f}", static_cast<double>(*g.host_start_ns) / 1e6)
                                   : "-",
                   opt_us(g.span.gpu_ns),
                   fmtu::fixed(fmtu::per_second(g.span.ops, g.span.gpu_ns), 0)});
        }
        s.print(out, kTextColumns);
        if (r.gpu_spans_total > shown)
            out << format("({} more spans in --json)\n", r.gpu_spans_total - shown);
    }
}

}  // namespace

void render_text(const AnalysisReport& r, std::ostream& out) {
    std::string name = r.trace_name.empty() ? "(unnamed trace)" : r.trace_name;
    for (char& ch : name)
        if (static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f) ch = '?';
    if (name.size() > 80) name = "~" + name.substr(name.size() - 79);
    out << format("clastrace analyze: {}\n", name);
    TextTable totals;
    totals.column("commands")
        .column("submissions")
        .column("ops")
        .column("objects")
        .column("triangles");
    totals.column("regions").column("overlap events").column("hazards");
    totals.row({num(r.commands), num(r.submissions), num(r.ops), num(r.objects), num(r.triangles),
                num(r.regions), num(r.overlap_events), num(r.hazards_total)});
    out << '\n';
    totals.print(out, kTextColumns);
    if (r.commands)
        out << format("largest submission: #{}, {} commands, {} ops\n", r.largest_submission,
                      r.largest_submission_commands, r.largest_submission_ops);
    sizes_section(r, out);
    commands_section(r, out);
    overlap_section(r, out);
    timing_section(r, out);
    if (!r.notes.empty()) {
        heading(out, "Notes");
        for (const std::string& n : r.notes) {
            std::string line = n;
            for (char& ch : line)
                if (static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f) ch = '?';
            std::string prefix = "- ";  // wrapped at the terminal width
            while (prefix.size() + line.size() > kTextColumns) {
                const std::size_t room = kTextColumns - prefix.size();
                std::size_t cut = line.rfind(' ', room);
                if (cut == std::string::npos || cut == 0) cut = room;
                out << prefix << line.substr(0, cut) << '\n';
                line = line.substr(cut + (cut < line.size() && line[cut] == ' ' ? 1 : 0));
                prefix = "  ";
            }
            out << prefix << line << '\n';
        }
    }
}

std::string render_text(const AnalysisReport& r) {
    std::ostringstream s;
    render_text(r, s);
    return s.str();
}

}  // namespace clastrace::analyze

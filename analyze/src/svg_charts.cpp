// SPDX-License-Identifier: Apache-2.0
#include "svg_charts.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <fmt/format.h>

#include "format_util.h"
#include "markup.h"

namespace clastrace::analyze {

using fmt::format;

const char* role_color(RegionRole role) {
    switch (role) {
    case RegionRole::kBuffer: return "#e8e8e8";
    case RegionRole::kScratch: return "#f2a65a";
    case RegionRole::kImplicitData: return "#7fb3d5";
    case RegionRole::kDstAddresses: return "#c39bd3";
    case RegionRole::kDstSizes: return "#d7bde2";
    case RegionRole::kSrcInfos: return "#82e0aa";
    case RegionRole::kSrcInfosCount: return "#abebc6";
    case RegionRole::kObjectClas: return "#2e86c1";
    case RegionRole::kObjectTemplate: return "#1abc9c";
    case RegionRole::kObjectBlas: return "#1f618d";
    case RegionRole::kVertex: return "#f7dc6f";
    case RegionRole::kIndex: return "#f0b27a";
    case RegionRole::kOther: return "#aab7b8";
    }
    return "#aab7b8";
}

namespace {

// Address axis. Addresses are cut into segments at every region boundary; unused ranges
// between them become thin breaks, and each segment gets a height growing with the square
// root of its bytes, so a 16-byte array stays visible next to a 256 MiB pool. Segments only a
// container buffer covers are drawn squeezed: what matters is what lives inside.
class AddressAxis {
public:
    struct Range {
        uint64_t begin, end;
        bool container;
    };
    struct Segment {
        uint64_t begin, end;
        double y, h;
        bool after_gap;
    };

    AddressAxis(const std::vector<Range>& ranges, double top, double height) {
        struct Event {
            uint64_t at;
            int content, container;
        };
        std::vector<Event> events;
        for (const Range& r : ranges) {
            events.push_back({r.begin, r.container ? 0 : 1, r.container ? 1 : 0});
            events.push_back({r.end, r.container ? 0 : -1, r.container ? -1 : 0});
        }
        std::sort(events.begin(), events.end(),
                  [](const Event& a, const Event& b) { return a.at < b.at; });
        std::vector<double> weight;
        int content = 0, container = 0;
        bool gap = false;
        for (std::size_t i = 0; i < events.size();) {
            const uint64_t at = events[i].at;
            for (; i < events.size() && events[i].at == at; ++i) {
                content += events[i].content;
                container += events[i].container;
            }
            if (i == events.size()) break;
            const uint64_t next = events[i].at;
            if (content == 0 && container == 0) {
                gap = true;
                continue;
            }
            const double root = std::sqrt(static_cast<double>(next - at));
            segments_.push_back({at, next, 0, 0, gap && !segments_.empty()});
            weight.push_back(content > 0 ? root : 0.3 * root);
            gap = false;
        }
        const std::size_t n = segments_.size();
        if (n == 0) return;
        std::size_t gaps = 0;
        for (const Segment& g : segments_) gaps += g.after_gap;
        const double gap_px = std::min(6.0, height * 0.15 / static_cast<double>(gaps + 1));
        const double min_h = std::min(1.5, height * 0.2 / static_cast<double>(n));
        const double usable =
            height - gap_px * static_cast<double>(gaps) - min_h * static_cast<double>(n);
        double total = 0;
        for (double w : weight) total += w;
        double y = top;
        for (std::size_t i = 0; i < n; ++i) {
            if (segments_[i].after_gap) y += gap_px;
            segments_[i].y = y;
            segments_[i].h = min_h + (total > 0 ? usable * weight[i] / total : 0.0);
            y += segments_[i].h;
        }
    }

    double y(uint64_t address) const {
        const Segment* g = find(address);
        if (!g) return segments_.empty() ? 0 : segments_.front().y;
        if (address >= g->end) return g->y + g->h;
        return g->y + g->h * static_cast<double>(address - g->begin) /
                          static_cast<double>(g->end - g->begin);
    }
    // y just past the last byte of a range ending (exclusive) at `end`.
    double y_end(uint64_t end) const {
        const Segment* g = find(end == 0 ? 0 : end - 1);
        if (!g) return segments_.empty() ? 0 : segments_.front().y;
        if (end > g->end) return g->y + g->h;
        return g->y +
               g->h * static_cast<double>(end - g->begin) / static_cast<double>(g->end - g->begin);
    }
    const std::vector<Segment>& segments() const { return segments_; }

private:
    const Segment* find(uint64_t address) const {
        auto it = std::upper_bound(segments_.begin(), segments_.end(), address,
                                   [](uint64_t a, const Segment& g) { return a < g.begin; });
        return it == segments_.begin() ? nullptr : &*std::prev(it);
    }
    std::vector<Segment> segments_;
};

}  // namespace

namespace {

// The memory map's plot area and its command axis: ordinal `first` at `left`, one command
// `width / span` wide.
struct MapFrame {
    double left, top, width, height;
    uint64_t first, last;
    double span;  // last - first + 1, in double (it may wrap in integers)
    double x(uint64_t ordinal) const {
        return left + width * static_cast<double>(ordinal - first) / span;
    }
};

// Address labels at segment starts, thinned so they do not collide; breaks mark cut gaps.
void append_address_labels(const AddressAxis& axis, const MapFrame& f, std::string& s) {
    double last_label = -100;
    for (const auto& g : axis.segments()) {
        if (g.after_gap)
            s += format(
                "<line class=\"gap\" x1=\"{}\" x2=\"{:.1f}\" y1=\"{:.2f}\" y2=\"{:.2f}\"/>\n",
                f.left - 4, f.left + f.width, g.y - 1.5, g.y - 1.5);
        if (g.y - last_label >= 13) {
            s +=
                format("<text class=\"axis\" x=\"{}\" y=\"{:.2f}\" text-anchor=\"end\">{}</text>\n",
                       f.left - 6, g.y + 4, fmtu::hex(g.begin));
            last_label = g.y;
        }
    }
}

// Buffers first (containers, drawn behind what they hold), then everything else.
void append_regions(const std::vector<const RegionRow*>& drawn, const AddressAxis& axis,
                    const MapFrame& f, std::string& s) {
    for (int pass = 0; pass < 2; ++pass) {
        for (const RegionRow* g : drawn) {
            if ((g->role == RegionRole::kBuffer) != (pass == 0)) continue;
            double x0 = f.x(g->first_command),
                   x1 = std::max(f.x(g->last_command) + f.width / f.span, x0 + 2.0);
            double y0 = axis.y(g->base), y1 = std::max(axis.y_end(g->base + g->size), y0 + 1.0);
            s += format(
                "<rect class=\"region role-{}\" data-region=\"{}\" x=\"{:.2f}\" y=\"{:.2f}\" "
                "width=\"{:.2f}\" "
                "height=\"{:.2f}\" fill=\"{}\"><title>{} {} [{}, +{}) commands "
                "{}..{}</title></rect>\n",
                region_role_name(g->role), g->id, x0, y0, x1 - x0, y1 - y0, role_color(g->role),
                region_role_name(g->role), escape_markup(g->label), fmtu::hex(g->base), g->size,
                g->first_command, g->last_command);
            if (pass == 1 && y1 - y0 >= 12 && x1 - x0 >= 70 && !g->label.empty())
                s += format("<text class=\"region-label\" x=\"{:.2f}\" y=\"{:.2f}\">{}</text>\n",
                            x0 + 3, y0 + 11,
                            escape_markup(traces::utf8_prefix(g->label, static_cast<std::size_t>(
                                                                            (x1 - x0) / 6.5))));
        }
    }
}

// Hazards and aliasing are always outlined, hazards on top; ordered reuse only while few
// enough to read (a frame loop reuses every buffer every frame). Returns the ordered-reuse
// pairs left without an outline.
std::size_t append_overlaps(const AnalysisReport& r, const AddressAxis& axis, const MapFrame& f,
                            std::string& s) {
    std::size_t reuse_pairs = 0;
    for (const OverlapRow& o : r.overlaps)
        reuse_pairs += !o.hazard && o.kind == OverlapKind::kReuse;
    const bool outline_reuse = reuse_pairs <= kMaxOutlinedReuse;
    std::vector<const OverlapRow*> outlined;
    for (int rank = 2; rank >= 0; --rank)
        for (const OverlapRow& o : r.overlaps) {
            int k = o.hazard ? 0 : (o.kind == OverlapKind::kAliasing ? 1 : 2);
            if (k == rank && (k != 2 || outline_reuse)) outlined.push_back(&o);
        }
    for (const OverlapRow* op : outlined) {
        const OverlapRow& o = *op;
        double x0 = f.x(o.older_command),
               x1 = std::max(f.x(o.newer_command) + f.width / f.span, x0 + 2.0);
        double y0 = axis.y(o.base), y1 = std::max(axis.y_end(o.base + o.size), y0 + 2.0);
        const char* cls =
            o.hazard ? "hazard" : (o.kind == OverlapKind::kAliasing ? "aliasing" : "reuse");
        s += format(
            "<rect class=\"overlap {}\" x=\"{:.2f}\" y=\"{:.2f}\" width=\"{:.2f}\" "
            "height=\"{:.2f}\">"
            "<title>{}: {} (cmd {}) and {} (cmd {}) share [{}, +{})</title></rect>\n",
            cls, x0, y0, x1 - x0, y1 - y0, o.hazard ? "HAZARD" : overlap_kind_name(o.kind),
            escape_markup(o.older_label), o.older_command, escape_markup(o.newer_label),
            o.newer_command, fmtu::hex(o.base), o.size);
    }
    return outline_reuse ? 0 : reuse_pairs;
}

// Command axis: at most nine ticks, whatever the ordinals (they may span all of 2^64).
void append_command_axis(const MapFrame& f, std::size_t omitted, std::size_t unoutlined_reuse,
                         std::string& s) {
    const double axis_y = f.top + f.height + 4;
    s += format("<line class=\"axis-line\" x1=\"{}\" x2=\"{}\" y1=\"{}\" y2=\"{}\"/>\n", f.left,
                f.left + f.width, axis_y, axis_y);
    const uint64_t step = (f.last - f.first) / 8 + 1;
    for (uint64_t i = 0, o = f.first; i < 9; ++i, o += step) {
        s += format("<text class=\"axis\" x=\"{:.1f}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n",
                    f.x(o) + f.width / f.span / 2, axis_y + 14, o);
        if (f.last - o < step) break;
    }
    s += format(
        "<text class=\"axis-title\" x=\"{}\" y=\"{}\" text-anchor=\"middle\">command "
        "ordinal{}</text>\n",
        f.left + f.width / 2, axis_y + 32,
        (omitted ? format(" ({} smaller regions not drawn)", omitted) : std::string()) +
            (unoutlined_reuse == 0
                 ? std::string()
                 : format(" ({} ordered-reuse pairs not outlined)", unoutlined_reuse)));
}

}  // namespace

std::string svg_memory_map(const AnalysisReport& r) {
    const double left = 120, top = 20, width = 840, height = 520, bottom_axis = 40;
    std::vector<const RegionRow*> drawn;
    for (const RegionRow& g : r.region_rows)
        if (g.size > 0) drawn.push_back(&g);
    std::size_t omitted = 0;
    if (drawn.size() > kMaxMapRegions) {
        std::stable_sort(drawn.begin(), drawn.end(),
                         [](const RegionRow* a, const RegionRow* b) { return a->size > b->size; });
        omitted = drawn.size() - kMaxMapRegions;
        drawn.resize(kMaxMapRegions);
    }
    std::string s = format(
        "<svg id=\"memory-map\" class=\"chart\" role=\"img\" width=\"{}\" height=\"{}\" "
        "viewBox=\"0 0 {} {}\">\n"
        "<title>Address space over time: regions by role, overlaps outlined</title>\n",
        left + width + 20, top + height + bottom_axis + 10, left + width + 20,
        top + height + bottom_axis + 10);
    if (drawn.empty()) {
        s += format("<text x=\"{}\" y=\"{}\">no regions</text>\n</svg>\n", left, top + 20);
        return s;
    }
    uint64_t first = UINT64_MAX, last = 0;
    std::vector<AddressAxis::Range> ranges;
    for (const RegionRow* g : drawn) {
        first = std::min(first, g->first_command);
        last = std::max(last, g->last_command);
        ranges.push_back({g->base, g->base + g->size, g->role == RegionRole::kBuffer});
    }
    for (const OverlapRow& o : r.overlaps) {
        first = std::min(first, o.older_command);
        last = std::max(last, o.newer_command);
    }
    const AddressAxis axis(ranges, top, height);
    const MapFrame frame{
        left, top, width, height, first, last, static_cast<double>(last - first) + 1.0};
    append_address_labels(axis, frame, s);
    append_regions(drawn, axis, frame, s);
    const std::size_t unoutlined_reuse = append_overlaps(r, axis, frame, s);
    append_command_axis(frame, omitted, unoutlined_reuse, s);
    s += "</svg>\n";
    return s;
}

std::string svg_size_histogram(const OpTypeSizes& t) {
    const auto& bins = t.engine_bytes.log2_bins();
    int lo = -1, hi = -1;
    uint64_t peak = 0;
    for (int b = 0; b < ValueDistribution::kLog2Bins; ++b) {
        if (bins[b] == 0) continue;
        if (lo < 0) lo = b;
        hi = b;
        peak = std::max(peak, bins[b]);
    }
    const double left = 50, top = 20, plot_h = 160, bar_w = 44;
    const int n = lo < 0 ? 0 : hi - lo + 1;
    const double width = left + bar_w * n + 20, height = top + plot_h + 50;
    std::string s = format(
        "<svg id=\"hist-{}\" class=\"chart histogram\" role=\"img\" width=\"{}\" height=\"{}\" "
        "viewBox=\"0 0 {} {}\">\n"
        "<title>Object bytes, {}: {} objects in log2 bins</title>\n",
        op_type_name(t.op_type), std::max(width, 240.0), height, std::max(width, 240.0), height,
        op_type_name(t.op_type), t.objects);
    s += format("<line class=\"axis-line\" x1=\"{}\" x2=\"{}\" y1=\"{}\" y2=\"{}\"/>\n", left,
                left + bar_w * n, top + plot_h, top + plot_h);
    for (int b = lo; n > 0 && b <= hi; ++b) {
        const double h =
            peak ? plot_h * static_cast<double>(bins[b]) / static_cast<double>(peak) : 0;
        const double bx = left + bar_w * (b - lo);
        const uint64_t low = ValueDistribution::bin_low(b);
        const uint64_t high =
            b == 0 ? 0 : (b == 64 ? UINT64_MAX : ValueDistribution::bin_low(b + 1) - 1);
        s += format(
            "<rect class=\"bar\" data-low=\"{}\" data-high=\"{}\" data-count=\"{}\" x=\"{:.1f}\" "
            "y=\"{:.2f}\" "
            "width=\"{}\" height=\"{:.2f}\"><title>{}..{} bytes: {} objects</title></rect>\n",
            low, high, bins[b], bx + 3, top + plot_h - h, bar_w - 6, h, low, high, bins[b]);
        if (bins[b])
            s += format(
                "<text class=\"count\" x=\"{:.1f}\" y=\"{:.2f}\" "
                "text-anchor=\"middle\">{}</text>\n",
                bx + bar_w / 2, top + plot_h - h - 3, bins[b]);
        s += format("<text class=\"axis\" x=\"{:.1f}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n",
                    bx + bar_w / 2, top + plot_h + 14, fmtu::human_bytes(low));
    }
    s += format("<text class=\"axis-title\" x=\"{}\" y=\"{}\">object bytes (bin low end)</text>\n",
                left, top + plot_h + 36);
    s += "</svg>\n";
    return s;
}

std::string svg_timeline(const AnalysisReport& r) {
    const double left = 70, top = 20, plot_w = 880, plot_h = 200;
    const std::size_t n = r.timeline.size();
    std::string s = format(
        "<svg id=\"timeline\" class=\"chart\" role=\"img\" width=\"{}\" height=\"{}\" viewBox=\"0 "
        "0 {} {}\">\n"
        "<title>Time per command: GPU timestamps and replay engine</title>\n",
        left + plot_w + 20, top + plot_h + 60, left + plot_w + 20, top + plot_h + 60);
    uint64_t peak = 0;
    for (const TimelineBucket& b : r.timeline) peak = std::max({peak, b.replay_ns, b.gpu_ns});
    if (n == 0 || peak == 0) {
        s += format("<text x=\"{}\" y=\"{}\">no timing recorded</text>\n</svg>\n", left, top + 20);
        return s;
    }
    std::set<uint64_t> listed;
    for (const CommandRow& c : r.commands_listed) listed.insert(c.ordinal);
    const double slot = plot_w / static_cast<double>(n);
    const bool both = r.gpu_timing_present && r.replay_timing_present;
    const double bar = std::max(0.5, (both ? slot / 2 : slot) * 0.85);
    auto bar_rect = [&](const char* cls, double bx, uint64_t ns, const TimelineBucket& b) {
        const double h = plot_h * static_cast<double>(ns) / static_cast<double>(peak);
        return format(
            "<rect class=\"{}\" data-first=\"{}\" data-last=\"{}\" data-ns=\"{}\" x=\"{:.2f}\" "
            "y=\"{:.2f}\" "
            "width=\"{:.2f}\" height=\"{:.2f}\"><title>commands {}..{}: {} {} ms</title></rect>",
            cls, b.first_ordinal, b.last_ordinal, ns, bx, top + plot_h - h, bar, h, b.first_ordinal,
            b.last_ordinal, cls, fmtu::ms(ns));
    };
    for (std::size_t i = 0; i < n; ++i) {
        const TimelineBucket& b = r.timeline[i];
        const double bx = left + slot * static_cast<double>(i);
        const bool link = b.commands == 1 && listed.count(b.first_ordinal);
        if (link) s += format("<a href=\"#cmd-{}\">", b.first_ordinal);
        if (r.replay_timing_present) s += bar_rect("replay", bx, b.replay_ns, b);
        if (r.gpu_timing_present) s += bar_rect("gpu", bx + (both ? slot / 2 : 0), b.gpu_ns, b);
        if (link) s += "</a>";
        s += '\n';
    }
    s += format("<line class=\"axis-line\" x1=\"{}\" x2=\"{}\" y1=\"{}\" y2=\"{}\"/>\n", left,
                left + plot_w, top + plot_h, top + plot_h);
    s += format("<text class=\"axis\" x=\"{}\" y=\"{}\" text-anchor=\"end\">{} ms</text>\n",
                left - 4, top + 8, fmtu::ms(peak));
    s += format("<text class=\"axis\" x=\"{}\" y=\"{}\" text-anchor=\"end\">0</text>\n", left - 4,
                top + plot_h);
    const std::size_t step = std::max<std::size_t>(1, (n + 7) / 8);
    for (std::size_t i = 0; i < n; i += step)
        s += format("<text class=\"axis\" x=\"{:.1f}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n",
                    left + slot * (static_cast<double>(i) + 0.5), top + plot_h + 14,
                    r.timeline[i].first_ordinal);
    s += format(
        "<text class=\"axis-title\" x=\"{}\" y=\"{}\" text-anchor=\"middle\">command "
        "ordinal{}</text>\n",
        left + plot_w / 2, top + plot_h + 34,
        r.timeline.front().commands > 1 || r.timeline.back().commands > 1
            ? " (bars sum runs of commands)"
            : "");
    s += "</svg>\n";
    return s;
}

std::string svg_gpu_spans(const AnalysisReport& r) {
    const double left = 70, top = 20, plot_w = 880, lane_h = 28;
    uint64_t end = 0;
    for (const GpuSpanRow& g : r.gpu_spans) end = std::max(end, g.start_ns + g.span.gpu_ns);
    std::string s = format(
        "<svg id=\"gpu-timeline\" class=\"chart\" role=\"img\" width=\"{}\" height=\"{}\" "
        "viewBox=\"0 0 {} {}\">\n"
        "<title>GPU timestamp spans on the device clock</title>\n",
        left + plot_w + 20, top + lane_h + 50, left + plot_w + 20, top + lane_h + 50);
    if (r.gpu_spans.empty() || end == 0) {
        s += format("<text x=\"{}\" y=\"{}\">no GPU timestamps recorded</text>\n</svg>\n", left,
                    top + 20);
        return s;
    }
    std::set<uint64_t> listed;
    for (const CommandRow& c : r.commands_listed) listed.insert(c.ordinal);
    const double scale = plot_w / static_cast<double>(end);
    for (const GpuSpanRow& g : r.gpu_spans) {
        const double x = left + scale * static_cast<double>(g.start_ns);
        const double w = std::max(1.0, scale * static_cast<double>(g.span.gpu_ns));
        const bool link = listed.count(g.span.first_ordinal) > 0;
        if (link) s += format("<a href=\"#cmd-{}\">", g.span.first_ordinal);
        s += format(
            "<rect class=\"gpu-span gpu\" data-first=\"{}\" data-last=\"{}\" data-start-ns=\"{}\" "
            "data-ns=\"{}\" "
            "data-ops=\"{}\" x=\"{:.2f}\" y=\"{}\" width=\"{:.2f}\" height=\"{}\"><title>commands "
            "{}..{}: {} ops, {} ms"
            "</title></rect>",
            g.span.first_ordinal, g.span.last_ordinal, g.start_ns, g.span.gpu_ns, g.span.ops, x,
            top, w, lane_h, g.span.first_ordinal, g.span.last_ordinal, g.span.ops,
            fmtu::ms(g.span.gpu_ns));
        if (link) s += "</a>";
        s += '\n';
    }
    s += format("<line class=\"axis-line\" x1=\"{}\" x2=\"{}\" y1=\"{}\" y2=\"{}\"/>\n", left,
                left + plot_w, top + lane_h, top + lane_h);
    s += format("<text class=\"axis\" x=\"{}\" y=\"{}\" text-anchor=\"start\">0</text>\n", left,
                top + lane_h + 14);
    s += format("<text class=\"axis\" x=\"{}\" y=\"{}\" text-anchor=\"end\">{} ms</text>\n",
                left + plot_w, top + lane_h + 14, fmtu::ms(end));
    s += format(
        "<text class=\"axis-title\" x=\"{}\" y=\"{}\" text-anchor=\"middle\">GPU time since the "
        "first span</text>\n",
        left + plot_w / 2, top + lane_h + 34);
    s += "</svg>\n";
    return s;
}

std::string svg_size_budget(const AnalysisReport& r) {
    struct Row {
        std::string label;
        uint64_t part, whole;
        const char* what;
    };
    std::vector<Row> rows;
    for (const OpTypeSizes& t : r.by_op_type) {
        if (t.commands == 0) continue;
        const std::string op = op_type_name(t.op_type);
        if (t.commands_with_query)
            rows.push_back({op + ": objects / worst case", t.actual_bytes_of_queried,
                            t.worst_case_bytes, "objects"});
        if (t.implicit_allocated)
            rows.push_back({op + ": implicit data used / allocated", t.implicit_used,
                            t.implicit_allocated, "implicit"});
        if (t.scratch_allocated)
            rows.push_back({op + ": scratch required / allocated", t.scratch_required,
                            t.scratch_allocated, "scratch"});
    }
    const double label_w = 330, bar_w = 560, row_h = 26, top = 10;
    const double height = top + row_h * static_cast<double>(rows.size()) + 10;
    std::string s = format(
        "<svg id=\"size-budget\" class=\"chart\" role=\"img\" width=\"{}\" height=\"{}\" "
        "viewBox=\"0 0 {} {}\">\n"
        "<title>How full each budget is: filled part of each bar, whole bar the larger "
        "value</title>\n",
        label_w + bar_w + 160, std::max(height, 40.0), label_w + bar_w + 160,
        std::max(height, 40.0));
    if (rows.empty())
        return s + format(
                       "<text x=\"10\" y=\"24\">no build-sizes queries or "
                       "allocations</text>\n</svg>\n");
    for (std::size_t i = 0; i < rows.size(); ++i) {
        const Row& row = rows[i];
        const double y = top + row_h * static_cast<double>(i);
        const uint64_t scale = std::max(row.part, row.whole);
        const double fill =
            scale ? bar_w * static_cast<double>(row.part) / static_cast<double>(scale) : 0;
        const double whole =
            scale ? bar_w * static_cast<double>(row.whole) / static_cast<double>(scale) : 0;
        const bool over = row.part > row.whole;  // e.g. objects larger than the query's worst case
        s += format("<text class=\"axis\" x=\"{}\" y=\"{:.1f}\" text-anchor=\"end\">{}</text>\n",
                    label_w - 8, y + 15, escape_markup(row.label));
        s += format(
            "<rect class=\"budget-whole\" x=\"{}\" y=\"{:.1f}\" width=\"{:.2f}\" height=\"18\"/>",
            label_w, y + 2, whole);
        s += format(
            "<rect class=\"budget-part {}{}\" data-part=\"{}\" data-whole=\"{}\" x=\"{}\" "
            "y=\"{:.1f}\" width=\"{:.2f}\" "
            "height=\"18\"><title>{}: {} of {} bytes</title></rect>",
            row.what, over ? " over" : "", row.part, row.whole, label_w, y + 2, fill,
            escape_markup(row.label), row.part, row.whole);
        s += format("<text class=\"count\" x=\"{:.1f}\" y=\"{:.1f}\">{} of {} ({})</text>\n",
                    label_w + bar_w + 6, y + 15, fmtu::human_bytes(row.part),
                    fmtu::human_bytes(row.whole), fmtu::percent(fmtu::ratio(row.part, row.whole)));
    }
    return s + "</svg>\n";
}

std::string svg_truncation(const AnalysisReport& r) {
    const double left = 60, top = 20, plot_h = 140, bar_w = 48;
    const std::size_t n = r.truncation.size();
    const double width = std::max(left + bar_w * static_cast<double>(n) + 20, 260.0);
    std::string s = format(
        "<svg id=\"truncation-chart\" class=\"chart\" role=\"img\" width=\"{}\" height=\"{}\" "
        "viewBox=\"0 0 {} {}\">\n"
        "<title>Bytes per triangle by positionTruncateBitCount</title>\n",
        width, top + plot_h + 50, width, top + plot_h + 50);
    double peak = 0;
    for (const TruncationRow& t : r.truncation)
        peak = std::max(peak, fmtu::ratio(t.engine_bytes, t.triangles).value_or(0.0));
    for (std::size_t i = 0; i < n; ++i) {
        const TruncationRow& t = r.truncation[i];
        const double v = fmtu::ratio(t.engine_bytes, t.triangles).value_or(0.0);
        const double h = peak > 0 ? plot_h * v / peak : 0;
        const double x = left + bar_w * static_cast<double>(i);
        s += format(
            "<rect class=\"bar\" data-bits=\"{}\" data-bytes-per-triangle=\"{:.2f}\" x=\"{:.1f}\" "
            "y=\"{:.2f}\" width=\"{}\" "
            "height=\"{:.2f}\"><title>{} bits: {:.2f} bytes/triangle over {} "
            "objects</title></rect>\n",
            t.truncate_bits, v, x + 4, top + plot_h - h, bar_w - 8, h, t.truncate_bits, v,
            t.objects);
        s += format(
            "<text class=\"count\" x=\"{:.1f}\" y=\"{:.2f}\" "
            "text-anchor=\"middle\">{:.1f}</text>\n",
            x + bar_w / 2, top + plot_h - h - 3, v);
        s += format("<text class=\"axis\" x=\"{:.1f}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n",
                    x + bar_w / 2, top + plot_h + 14, t.truncate_bits);
    }
    s += format("<line class=\"axis-line\" x1=\"{}\" x2=\"{:.1f}\" y1=\"{}\" y2=\"{}\"/>\n", left,
                left + bar_w * static_cast<double>(n), top + plot_h, top + plot_h);
    s += format("<text class=\"axis-title\" x=\"{}\" y=\"{}\">positionTruncateBitCount</text>\n",
                left, top + plot_h + 34);
    return s + "</svg>\n";
}

}  // namespace clastrace::analyze

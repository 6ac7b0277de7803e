// SPDX-License-Identifier: Apache-2.0
// One report for the hazards one missing barrier causes once per op.
#include "replayer_internal.h"

#include <map>
#include <tuple>

namespace clastrace::replay::detail {


// The engine reports accesses per op, so one missing barrier before a build would show
// once per op. Hazards of one class between the same two commands over the same prior
// field become one report whose later field names the ops as [*] and whose ranges cover them all.
std::vector<HazardReport> merge_per_op_hazards(const std::vector<HazardReport>& hazards,
                                               uint64_t* merged) {
    std::vector<HazardReport> out;
    using CommandKey = decltype(command_place_key(CommandRef{}));
    std::map<std::tuple<int, CommandKey, CommandKey, std::string, std::string>, size_t> index;
    for (const HazardReport& h : hazards) {
        auto key =
            std::make_tuple(int(h.hazard), command_place_key(h.prior.command),
                            command_place_key(h.later.command), hazard_field_family(h.prior.field),
                            hazard_field_family(h.later.field));
        auto [it, inserted] = index.emplace(key, out.size());
        if (inserted) {
            out.push_back(h);
            continue;
        }
        ++*merged;
        HazardReport& m = out[it->second];
        m.later.field = folded_hazard_field(m.later.field, h.later.field);
        m.prior.field = folded_hazard_field(m.prior.field, h.prior.field);
        m.later.range = {std::min(m.later.range.begin, h.later.range.begin),
                         std::max(m.later.range.end, h.later.range.end)};
        m.prior.range = {std::min(m.prior.range.begin, h.prior.range.begin),
                         std::max(m.prior.range.end, h.prior.range.end)};
        m.overlap = {std::min(m.overlap.begin, h.overlap.begin),
                     std::max(m.overlap.end, h.overlap.end)};
    }
    return out;
}

}  // namespace clastrace::replay::detail

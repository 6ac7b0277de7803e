// SPDX-License-Identifier: Apache-2.0
// The closure of what a consumer reads (structure_reachability.h).
#include "structure_reachability.h"

#include <clastrace/common/hex.h>

#include <algorithm>
#include <cstring>

namespace clastrace::replay::detail {

using common::hex;

std::vector<uint64_t> packed_instance_references(std::span<const uint8_t> bytes, uint32_t count) {
    std::vector<uint64_t> out;
    const uint64_t whole = std::min<uint64_t>(count, bytes.size() / kInstanceBytes);
    out.reserve(whole);
    for (uint64_t i = 0; i < whole; ++i) {
        uint64_t reference = 0;
        std::memcpy(&reference, bytes.data() + i * kInstanceBytes + kInstanceReferenceOffset, 8);
        out.push_back(reference);
    }
    return out;
}

void StructureReachability::on_created(uint64_t handle, uint64_t reference) {
    on_destroyed(handle);  // a reused handle starts over
    if (reference == 0) return;
    by_reference_[reference] = handle;
    reference_of_[handle] = reference;
}

void StructureReachability::on_destroyed(uint64_t handle) {
    instances_.erase(handle);
    written_.erase(handle);
    auto it = reference_of_.find(handle);
    if (it == reference_of_.end()) return;
    if (auto by = by_reference_.find(it->second); by != by_reference_.end() && by->second == handle)
        by_reference_.erase(by);
    reference_of_.erase(it);
}

void StructureReachability::on_top_level_built(uint64_t handle, std::vector<uint64_t> references) {
    instances_[handle] = std::move(references);
}

std::optional<uint64_t> StructureReachability::handle_of(uint64_t reference) const {
    auto it = by_reference_.find(reference);
    if (it == by_reference_.end()) return std::nullopt;
    return it->second;
}

std::vector<uint64_t> StructureReachability::top_levels_naming(uint64_t handle) const {
    std::vector<uint64_t> out;
    auto ref = reference_of_.find(handle);
    if (ref == reference_of_.end()) return out;
    for (const auto& [top, references] : instances_)
        if (std::find(references.begin(), references.end(), ref->second) != references.end())
            out.push_back(top);
    std::sort(out.begin(), out.end());
    return out;
}

std::vector<ReachedStructure> StructureReachability::reach(uint64_t handle, uint64_t address,
                                                           const std::string& root) const {
    std::vector<ReachedStructure> out;
    if (handle != 0)
        add_object(handle, root, &out);
    else if (address != 0)
        add_reference(address, root, &out);
    return out;
}

void StructureReachability::add_reference(uint64_t reference, const std::string& path,
                                          std::vector<ReachedStructure>* out) const {
    if (std::optional<uint64_t> h = handle_of(reference)) {
        add_object(*h, path, out);
        return;
    }
    // No created object has that address: a cluster bottom level (it has no handle).
    if (std::optional<ClusterBottomLevel> blas = cluster_lookup_(reference))
        add_clusters(*blas, reference, path, out);
}

void StructureReachability::add_object(uint64_t handle, const std::string& path,
                                       std::vector<ReachedStructure>* out) const {
    for (const ReachedStructure& r : *out)
        if (r.handle == handle) return;  // two instances of one bottom level: read once
    const auto instances = instances_.find(handle);
    const bool top = instances != instances_.end();
    const std::string here = path + (path.empty() ? "" : ": ") + (top ? "top level " : "") +
                             (top || path.empty() ? "" : "bottom level ") + hex(handle);
    if (std::optional<AddressRange> range = object_range_(handle); range && !range->empty())
        out->push_back({handle, *range, here, written(handle)});
    if (!top) return;
    const std::vector<uint64_t>& references = instances->second;
    for (size_t i = 0; i < references.size(); ++i)
        if (references[i] != 0)  // 0: an inactive instance
            add_reference(references[i], here + " > instance " + std::to_string(i), out);
}

void StructureReachability::add_clusters(const ClusterBottomLevel& blas, uint64_t address,
                                         const std::string& path,
                                         std::vector<ReachedStructure>* out) const {
    auto seen = [&](const AddressRange& r) {
        return std::any_of(out->begin(), out->end(),
                           [&](const ReachedStructure& s) { return s.range == r; });
    };
    const std::string here =
        path + (path.empty() ? "" : ": ") + "cluster bottom level " + hex(address);
    if (!seen(blas.range)) out->push_back({0, blas.range, here, true});
    for (const ClusterBottomLevel::Cluster& c : blas.clusters)
        if (!seen(c.range))
            out->push_back({0, c.range,
                            here + " > cluster " + std::to_string(c.reference_index) + ": CLAS " +
                                hex(c.range.begin),
                            true});
}

}  // namespace clastrace::replay::detail

// SPDX-License-Identifier: Apache-2.0
#include "address_owners.h"

namespace clastrace::analyze {

void AddressOwners::paint(uint64_t base, uint64_t size, const AddressOwner& owner,
                          std::vector<OwnerOverlap>& taken) {
    if (size == 0) return;
    const uint64_t end = base + size;
    auto it = spans_.upper_bound(base);
    if (it != spans_.begin() && std::prev(it)->second.end > base) --it;

    // Remainders of spans cut at either edge survive with their old owner.
    std::vector<std::pair<uint64_t, Span>> keep;
    while (it != spans_.end() && it->first < end) {
        const uint64_t s = it->first, e = it->second.end;
        const AddressOwner& old = it->second.owner;
        const uint64_t lo = s > base ? s : base, hi = e < end ? e : end;
        if (old.region != owner.region) taken.push_back({old, lo, hi - lo});
        if (s < base) keep.push_back({s, {base, old}});
        if (e > end) keep.push_back({end, {e, old}});
        it = spans_.erase(it);
    }
    for (auto& k : keep) spans_.emplace(k.first, k.second);
    auto placed = spans_.emplace(base, Span{end, owner}).first;

    // Rejoin with neighbours of the same owner, so repeated uses do not fragment the map.
    auto same = [](const AddressOwner& a, const AddressOwner& b) {
        return a.region == b.region && a.role == b.role && a.command == b.command;
    };
    auto next = std::next(placed);
    if (next != spans_.end() && next->first == placed->second.end &&
        same(next->second.owner, owner)) {
        placed->second.end = next->second.end;
        spans_.erase(next);
    }
    if (placed != spans_.begin()) {
        auto prev = std::prev(placed);
        if (prev->second.end == placed->first && same(prev->second.owner, owner)) {
            prev->second.end = placed->second.end;
            spans_.erase(placed);
        }
    }
}

}  // namespace clastrace::analyze

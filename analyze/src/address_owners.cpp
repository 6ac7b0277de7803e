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
  spans_.emplace(base, Span{end, owner});
}

}  // namespace clastrace::analyze

// SPDX-License-Identifier: Apache-2.0
// Which region last used each byte of device address space. A region use paints its range;
// the bytes it takes from other regions come back as OwnerOverlaps. Spans never overlap and
// their number is bounded by the distinct live extents, not by how often they are reused.
#pragma once

#include <cstdint>
#include <map>
#include <vector>

#include "clastrace/analyze/input.h"

namespace clastrace::analyze {

struct AddressOwner {
    uint64_t region = 0;
    RegionRole role = RegionRole::kOther;
    uint64_t command = 0;
    bool written = false;
};

struct OwnerOverlap {
    AddressOwner previous;
    uint64_t base = 0, size = 0;
};

class AddressOwners {
public:
    // Paints [base, base+size) with `owner`, appending to `taken` each span it covers that had
    // another region. base+size must not wrap (the caller checks).
    void paint(uint64_t base, uint64_t size, const AddressOwner& owner,
               std::vector<OwnerOverlap>& taken);
    std::size_t spans() const { return spans_.size(); }

private:
    struct Span {
        uint64_t end;
        AddressOwner owner;
    };
    std::map<uint64_t, Span> spans_;  // begin -> span
};

}  // namespace clastrace::analyze

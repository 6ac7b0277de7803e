// SPDX-License-Identifier: Apache-2.0
// The traversal arrays' allocator (engine/src/huge_pages.h): large arrays start on a 2 MiB
// boundary in a mapping marked for transparent huge pages and keep their bytes through growth;
// small ones come from operator new at their type's alignment.
#include "geometry/triangle4.h"
#include "huge_pages.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>

namespace clastrace::engine::detail {
namespace {

// The VmFlags line of the mapping of /proc/self/smaps that holds `p` ("" when none does).
std::string mapping_flags(const void* p) {
    const uintptr_t at = reinterpret_cast<uintptr_t>(p);
    std::ifstream smaps("/proc/self/smaps");
    std::string line;
    bool inside = false;
    while (std::getline(smaps, line)) {
        unsigned long long begin = 0, end = 0;
        if (std::sscanf(line.c_str(), "%llx-%llx ", &begin, &end) == 2 &&
            line.find(' ') > line.find('-')) {
            inside = at >= begin && at < end;
            continue;
        }
        if (inside && line.rfind("VmFlags:", 0) == 0) return line;
    }
    return "";
}

// Whether the kernel has transparent huge pages and this process may use them.
bool thp_allowed() {
    std::ifstream thp("/sys/kernel/mm/transparent_hugepage/enabled");
    std::string line;
    if (!std::getline(thp, line) || line.find("[never]") != std::string::npos) return false;
    std::ifstream status("/proc/self/status");
    while (std::getline(status, line))
        if (line.rfind("THP_enabled:", 0) == 0) return line.find('1') != std::string::npos;
    return true;
}

TEST(HugePages, ALargeArrayStartsOnAHugePageMarkedForHugePages) {
    HugePageVector<geometry::Triangle4> groups(kHugePageArrayBytes / sizeof(geometry::Triangle4) +
                                               1000);
    EXPECT_EQ(reinterpret_cast<uintptr_t>(groups.data()) % (uintptr_t(2) << 20), 0u);
    // madvise(MADV_HUGEPAGE) shows as "hg" (refused, no flag to see, where the kernel has no
    // THP or this process had it turned off with prctl(PR_SET_THP_DISABLE)).
    if (thp_allowed())
        EXPECT_NE(mapping_flags(groups.data()).find(" hg"), std::string::npos)
            << mapping_flags(groups.data());
    // The last element is writable: the mapping reaches past the final whole huge page.
    groups.back().primitive[3] = 7u;
    EXPECT_EQ(groups.back().primitive[3], 7u);
    EXPECT_EQ(groups.front().v[0][0], 0.0f);
}

TEST(HugePages, GrowingKeepsTheBytesAcrossTheThreshold) {
    HugePageVector<uint32_t> values;
    const uint32_t count = uint32_t(3 * kHugePageArrayBytes / sizeof(uint32_t));
    for (uint32_t k = 0; k < count; ++k) values.push_back(k * 2654435761u);
    bool same = true;
    for (uint32_t k = 0; k < count; ++k) same &= values[k] == k * 2654435761u;
    EXPECT_TRUE(same);
    EXPECT_EQ(reinterpret_cast<uintptr_t>(values.data()) % (uintptr_t(2) << 20), 0u);
    values.clear();
    values.shrink_to_fit();  // back below the threshold: operator delete of the right size
    EXPECT_EQ(values.capacity(), 0u);
}

TEST(HugePages, ASmallArrayKeepsItsTypesAlignment) {
    for (size_t n : {1, 3, 100}) {
        HugePageVector<geometry::Triangle4> groups(n);
        EXPECT_EQ(reinterpret_cast<uintptr_t>(groups.data()) % alignof(geometry::Triangle4), 0u)
            << n;
    }
}

}  // namespace
}  // namespace clastrace::engine::detail

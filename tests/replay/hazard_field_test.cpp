// SPDX-License-Identifier: Apache-2.0
#include <gtest/gtest.h>

#include "clastrace/replay/hazard_report.h"

namespace clastrace::replay {
namespace {

TEST(HazardField, FamilyDropsIndicesAndSizeNotes) {
    EXPECT_EQ(hazard_field_family("srcInfosArray[3].vertexBuffer"),
              "srcInfosArray[*].vertexBuffer");
    EXPECT_EQ(hazard_field_family("dstImplicitData[op 12]"), "dstImplicitData");
    EXPECT_EQ(hazard_field_family("dstImplicitData (the 4096-byte implicit region answered by "
                                  "the trace's query (nested))"),
              "dstImplicitData");
    EXPECT_EQ(hazard_field_family("scratchData"), "scratchData");
    // Not an index: kept as written.
    EXPECT_EQ(hazard_field_family("a[x]"), "a[x]");
    EXPECT_EQ(hazard_field_family("a[12"), "a[12");
    EXPECT_EQ(hazard_field_family(""), "");
}

TEST(HazardField, FamiliesPartDifferentFields) {
    EXPECT_NE(hazard_field_family("srcInfosArray[0].vertexBuffer"),
              hazard_field_family("srcInfosArray[0].indexBuffer"));
    EXPECT_NE(hazard_field_family("dstImplicitData[op 0]"), hazard_field_family("scratchData"));
}

TEST(HazardField, FoldedFieldKeepsTheSizeNote) {
    EXPECT_EQ(folded_hazard_field("x", "x"), "x");
    EXPECT_EQ(folded_hazard_field("srcInfosArray[0].vertexBuffer", "srcInfosArray[5].vertexBuffer"),
              "srcInfosArray[*].vertexBuffer");
    EXPECT_EQ(folded_hazard_field("dstImplicitData[op 0]", "dstImplicitData[op 1]"),
              "dstImplicitData[op *]");
    EXPECT_EQ(folded_hazard_field("dstImplicitData[op 0]", "dstImplicitData (the 32-byte region)"),
              "dstImplicitData (the 32-byte region)");
    EXPECT_EQ(folded_hazard_field("dstImplicitData (the 32-byte region)", "dstImplicitData[op 0]"),
              "dstImplicitData (the 32-byte region)");
}

}  // namespace
}  // namespace clastrace::replay

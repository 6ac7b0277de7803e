// SPDX-License-Identifier: Apache-2.0
// engine::FieldName, the text of a recorded access's field: inline up to kInline characters,
// on the heap beyond, the same text either way through copies, moves and appends.
#include <clastrace/engine/field_name.h>

#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <utility>

using clastrace::engine::FieldName;

TEST(FieldName, BuildsTheTextAStringWould) {
    FieldName name("srcInfosArray[");
    name.append_number(4294967295u).append("].vertexBuffer");
    EXPECT_EQ(name, "srcInfosArray[4294967295].vertexBuffer");
    EXPECT_EQ(name.view(), std::string("srcInfosArray[") + "4294967295" + "].vertexBuffer");
    EXPECT_EQ(std::string(name.c_str()), name.str());
    EXPECT_TRUE(name.starts_with("srcInfosArray["));
    EXPECT_TRUE(name.ends_with(".vertexBuffer"));
    EXPECT_EQ(name.find("["), 13u);
    EXPECT_EQ(name + " = 0x10", "srcInfosArray[4294967295].vertexBuffer = 0x10");
    EXPECT_EQ("at " + name, "at srcInfosArray[4294967295].vertexBuffer");
    std::ostringstream out;
    out << name;
    EXPECT_EQ(out.str(), name.str());
    EXPECT_TRUE(FieldName().empty());
    EXPECT_EQ(FieldName().c_str()[0], '\0');
    EXPECT_EQ(FieldName().append_number(0), "0");
}

// Names across the inline capacity: every length from empty to three times it, grown by
// appends, copied, moved and assigned both ways, keep their text.
TEST(FieldName, KeepsItsTextInlineAndOnTheHeap) {
    std::string expected;
    FieldName grown;
    for (size_t length = 0; length <= 3 * FieldName::kInline; ++length) {
        ASSERT_EQ(grown.view(), expected);
        ASSERT_EQ(grown.size(), length);
        ASSERT_EQ(grown.c_str()[length], '\0');
        FieldName copy(grown);
        FieldName assigned("x");
        assigned = grown;
        FieldName moved(std::move(copy));
        EXPECT_TRUE(copy.empty());  // NOLINT(bugprone-use-after-move): a moved-from name is empty
        FieldName move_assigned(std::string(2 * FieldName::kInline, 'y'));
        move_assigned = std::move(moved);
        ASSERT_EQ(assigned, expected);
        ASSERT_EQ(move_assigned, expected);
        ASSERT_EQ(move_assigned, grown);
        const char c = char('a' + length % 26);
        grown.append(std::string_view(&c, 1));
        expected.push_back(c);
    }
    FieldName self(expected);
    const FieldName& alias = self;
    self = alias;
    EXPECT_EQ(self, expected);
}

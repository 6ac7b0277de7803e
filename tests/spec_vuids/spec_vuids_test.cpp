// SPDX-License-Identifier: Apache-2.0
// Every VUID the code can emit names a rule of the spec: each "VUID-..." string literal in the
// product's sources is a VUID of the stored spec pages (docs/spec/vuids.tsv, made by
// scripts/extract_spec_vuids.py) or is listed, with its reason, in
// docs/spec/vuids_not_on_stored_pages.tsv. The sources are scanned when the test runs, so a new
// emit site is checked without a list to keep.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <cctype>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;

const fs::path kSourceDir = CLASTRACE_SOURCE_DIR;
// The parts whose code reports findings or issues (tests and docs are not emitters).
const char* const kProductParts[] = {"abi",    "common",  "traces",  "engine",
                                     "replay", "analyze", "capture", "tools"};

struct CatalogueRow {
    std::vector<std::string> columns;
    int line = 0;
};

// The rows of a tab-separated file, keyed by their first column; '#' lines are comments.
std::map<std::string, CatalogueRow> read_tsv(const fs::path& path) {
    std::map<std::string, CatalogueRow> rows;
    std::ifstream in(path);
    EXPECT_TRUE(in) << path << ": cannot be read";
    std::string line;
    for (int number = 1; std::getline(in, line); ++number) {
        if (line.empty() || line[0] == '#') continue;
        CatalogueRow row{{}, number};
        std::stringstream fields(line);
        for (std::string field; std::getline(fields, field, '\t');) row.columns.push_back(field);
        rows[row.columns[0]] = row;
    }
    return rows;
}

struct Literal {
    std::string text;
    int line = 0;
};

// The contents of a C++ source's ordinary string literals, comments skipped (a VUID named in a
// comment is emitted by nobody).
std::vector<Literal> string_literals(const std::string& source) {
    std::vector<Literal> literals;
    int line = 1;
    for (size_t i = 0; i < source.size(); ++i) {
        const char c = source[i];
        if (c == '\n') {
            ++line;
        } else if (source.compare(i, 2, "//") == 0) {
            while (i < source.size() && source[i] != '\n') ++i;
            --i;
        } else if (source.compare(i, 2, "/*") == 0) {
            const size_t end = source.find("*/", i + 2);
            const size_t stop = end == std::string::npos ? source.size() : end + 1;
            for (; i < stop; ++i) line += source[i] == '\n';
        } else if (c == '\'') {
            for (++i; i < source.size() && source[i] != '\''; ++i)
                if (source[i] == '\\') ++i;
        } else if (c == '"') {
            // Adjacent literals are one string, as the compiler joins them: clang-format splits
            // long VUID names across lines ("VUID-...-" "10484").
            Literal literal{{}, line};
            for (bool more = true; more;) {
                for (++i; i < source.size() && source[i] != '"'; ++i) {
                    if (source[i] == '\\') ++i;
                    literal.text += source[i];
                }
                size_t next = i + 1;
                int newlines = 0;
                for (; next < source.size() && std::isspace(uint8_t(source[next])); ++next)
                    newlines += source[next] == '\n';
                more = next < source.size() && source[next] == '"';
                if (more) i = next, line += newlines;
            }
            literals.push_back(literal);
        }
    }
    return literals;
}

struct EmitSite {
    std::string file;
    int line = 0;
};

// Every whole VUID name in a product source's string literals, with where it is written.
std::multimap<std::string, EmitSite> emitted_vuids() {
    static const std::regex kVuid("VUID-[A-Za-z0-9]+-[A-Za-z0-9]+-(?:[0-9]+|[a-z]+)");
    static const std::set<std::string> kSourceExtensions = {".cpp", ".h", ".hpp", ".c"};
    std::multimap<std::string, EmitSite> vuids;
    for (const char* part : kProductParts) {
        for (const auto& entry : fs::recursive_directory_iterator(kSourceDir / part)) {
            if (!entry.is_regular_file() || !kSourceExtensions.count(entry.path().extension()))
                continue;
            std::ifstream in(entry.path());
            const std::string source((std::istreambuf_iterator<char>(in)), {});
            const std::string file = fs::relative(entry.path(), kSourceDir).string();
            for (const Literal& literal : string_literals(source))
                for (std::sregex_iterator m(literal.text.begin(), literal.text.end(), kVuid), end;
                     m != end; ++m)
                    vuids.insert({m->str(), {file, literal.line}});
        }
    }
    return vuids;
}

const std::map<std::string, CatalogueRow>& catalogue() {
    static const auto rows = read_tsv(kSourceDir / "docs/spec/vuids.tsv");
    return rows;
}

const std::map<std::string, CatalogueRow>& not_on_stored_pages() {
    static const auto rows = read_tsv(kSourceDir / "docs/spec/vuids_not_on_stored_pages.tsv");
    return rows;
}

TEST(SpecVuids, ScannerFindsTheKnownEmitSites) {
    const auto vuids = emitted_vuids();
    // One from the engine, the replay and the capture layer: the scan reaches all three.
    EXPECT_TRUE(
        vuids.count("VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453"));
    EXPECT_TRUE(vuids.count("VUID-vkQueueSubmit-pSignalSemaphores-00067"));
    EXPECT_GE(vuids.size(), 100u);
    const auto literals = string_literals("// \"VUID-a-b-1\"\nx(\"VUID-c-d-2\", 'x'); /* \"e\" */");
    ASSERT_EQ(literals.size(), 1u);
    EXPECT_EQ(literals[0].text, "VUID-c-d-2");
    EXPECT_EQ(literals[0].line, 2);
    // Adjacent literals join, as the compiler joins them.
    const auto joined = string_literals("f(\"VUID-a-b-\"\n  \"10484\", \"x\");");
    ASSERT_EQ(joined.size(), 2u);
    EXPECT_EQ(joined[0].text, "VUID-a-b-10484");
    EXPECT_EQ(joined[1].text, "x");
}

TEST(SpecVuids, CatalogueRowsAreWholeEntries) {
    ASSERT_GE(catalogue().size(), 40u) << "docs/spec/vuids.tsv lost its rows";
    for (const auto& [vuid, row] : catalogue()) {
        ASSERT_EQ(row.columns.size(), 4u) << "docs/spec/vuids.tsv:" << row.line;
        EXPECT_FALSE(row.columns[3].empty()) << "docs/spec/vuids.tsv:" << row.line << " " << vuid;
    }
    for (const auto& [vuid, row] : not_on_stored_pages()) {
        ASSERT_EQ(row.columns.size(), 3u) << "docs/spec/vuids_not_on_stored_pages.tsv:" << row.line;
        EXPECT_FALSE(row.columns[1].empty()) << vuid << " has no reason";
    }
}

TEST(SpecVuids, EveryEmittedVuidIsOnAStoredPageOrListedWithAReason) {
    for (const auto& [vuid, site] : emitted_vuids())
        EXPECT_TRUE(catalogue().count(vuid) || not_on_stored_pages().count(vuid))
            << site.file << ":" << site.line << ": " << vuid
            << " is on no stored spec page and not in docs/spec/vuids_not_on_stored_pages.tsv";
}

TEST(SpecVuids, EveryListedExceptionIsStillEmittedAndNotOnAStoredPage) {
    const auto vuids = emitted_vuids();
    for (const auto& [vuid, row] : not_on_stored_pages()) {
        EXPECT_TRUE(vuids.count(vuid)) << "docs/spec/vuids_not_on_stored_pages.tsv:" << row.line
                                       << ": " << vuid << " is emitted nowhere any more";
        EXPECT_FALSE(catalogue().count(vuid))
            << "docs/spec/vuids_not_on_stored_pages.tsv:" << row.line << ": " << vuid
            << " is on a stored page now";
    }
}

// A VUID number names one rule: the same number under two names means one of them is wrong
// (a bad indexType was once reported as ...-indexType-10495, the vertex-stride rule's number).
TEST(SpecVuids, EachVuidNumberHasOneName) {
    static const std::regex kNumbered(".*-([0-9]+)$");
    std::map<std::string, std::set<std::string>> names_of_number;
    for (const auto& [vuid, site] : emitted_vuids()) {
        std::smatch m;
        if (std::regex_match(vuid, m, kNumbered)) names_of_number[m[1]].insert(vuid);
    }
    for (const auto& [number, names] : names_of_number) {
        std::string all;
        for (const std::string& name : names) all += "\n  " + name;
        EXPECT_EQ(names.size(), 1u) << "VUID number " << number << " under several names:" << all;
    }
}

}  // namespace

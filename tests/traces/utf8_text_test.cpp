// SPDX-License-Identifier: Apache-2.0
// The one rule that makes text UTF-8 (traces::valid_utf8), and the writer applying it to every
// string a trace stores.
#include "trace_test_support.h"

#include <clastrace/traces/utf8_text.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <fstream>
#include <regex>
#include <sstream>

namespace clastrace::traces::testing {
namespace {

const std::string R = "\xEF\xBF\xBD";  // U+FFFD

struct Repair {
    std::string bytes, text;
};

// Ill-formed input and what it becomes: one U+FFFD per maximal ill-formed subpart.
const std::vector<Repair>& ill_formed() {
    static const std::vector<Repair> cases = {
        {"caf\xE9", "caf" + R},               // Latin-1 é at the end: a 3-byte lead cut short
        {"caf\xE9.clt", "caf" + R + ".clt"},  // ... followed by what cannot continue it
        {"\xE9t\xE9", R + "t" + R},
        {"\x80", R},  // continuation bytes without a lead
        {"\x80\xBF", R + R},
        {"\xC0\x80", R + R},  // overlong forms: C0, C1 start nothing ...
        {"\xC1\xBF", R + R},
        {"\xE0\x80\x80", R + R + R},  // ... E0 and F0 only with their narrow second byte
        {"\xE0\x9F\xBF", R + R + R},
        {"\xF0\x80\x80\x80", R + R + R + R},
        {"\xF0\x8F\xBF\xBF", R + R + R + R},
        {"\xED\xA0\x80", R + R + R},  // surrogates U+D800, U+DFFF
        {"\xED\xBF\xBF", R + R + R},
        {"\xF4\x90\x80\x80", R + R + R + R},  // above U+10FFFF
        {"\xF5\x80\x80\x80", R + R + R + R},
        {"\xFE", R},
        {"\xFF", R},
        {"\xC3", R},  // cut short at the end, at every length
        {"\xE2\x82", R},
        {"\xF0\x9F\x98", R},
        {"\xE2\x82x", R + "x"},  // cut short by a byte that starts something else
        {"\xF0\x9F\x98\xC3\xA9", R + "\xC3\xA9"},
        {"a\xE2\x82\xAC"
         "b\xFF"
         "c",
         "a\xE2\x82\xAC"
         "b" +
             R + "c"},
        // Unicode's own example of the practice (chapter 3, U+FFFD substitution of maximal subparts)
        {"\x61\xF1\x80\x80\xE1\x80\xC2\x62\x80\x63\x80\xBF\x64",
         "a" + R + R + R + "b" + R + "c" + R + R + "d"},
    };
    return cases;
}

const std::vector<std::string>& well_formed() {
    static const std::vector<std::string> texts = {
        "",
        "plain ASCII",
        std::string("with\0nul", 8),
        "caf\xC3\xA9",
        "\xE2\x82\xAC",
        "\xF0\x9F\x98\x80",
        "\x7F",
        "\xC2\x80",
        "\xDF\xBF",  // first and last of one and two bytes
        "\xE0\xA0\x80",
        "\xED\x9F\xBF",
        "\xEE\x80\x80",  // around the surrogates
        "\xEF\xBF\xBF",
        "\xF0\x90\x80\x80",
        "\xF4\x8F\xBF\xBF"};
    return texts;
}

TEST(Utf8Text, WellFormedTextIsKept) {
    for (const std::string& text : well_formed()) {
        EXPECT_TRUE(is_valid_utf8(text)) << text;
        EXPECT_EQ(valid_utf8(text), text);
    }
}

TEST(Utf8Text, EachMaximalIllFormedSubpartBecomesOneReplacementCharacter) {
    for (const Repair& c : ill_formed()) {
        EXPECT_FALSE(is_valid_utf8(c.bytes)) << c.bytes;
        const std::string text = valid_utf8(c.bytes);
        EXPECT_EQ(text, c.text) << "from " << c.bytes;
        EXPECT_TRUE(is_valid_utf8(text));
    }
}

TEST(Utf8Text, PrefixesDoNotCutACharacter) {
    const std::string text =
        "ab\xE2\x82\xAC"
        "c\xF0\x9F\x98\x80";  // a b € c 😀
    EXPECT_EQ(utf8_prefix(text, 100), text);
    EXPECT_EQ(utf8_prefix(text, 2), "ab");
    EXPECT_EQ(utf8_prefix(text, 3), "ab");
    EXPECT_EQ(utf8_prefix(text, 4), "ab");
    EXPECT_EQ(utf8_prefix(text, 5), "ab\xE2\x82\xAC");
    EXPECT_EQ(utf8_prefix(text, 8),
              "ab\xE2\x82\xAC"
              "c");
    EXPECT_EQ(utf8_prefix(text, 9),
              "ab\xE2\x82\xAC"
              "c");
    EXPECT_EQ(utf8_prefix(text, 10), text);
    EXPECT_EQ(utf8_prefix("\xF0\x9F\x98\x80", 3), "");
    EXPECT_EQ(utf8_prefix("caf\xE9 au lait", 4), "caf\xE9");  // ill-formed bytes are cut as bytes
    EXPECT_EQ(utf8_prefix("\x80\x80\x80\x80\x80", 4), "\x80\x80\x80\x80");
}

// The JSON output dumps whole documents with nlohmann's `replace` handler: it must follow the
// same rule, so that a name reads the same in JSON, in HTML and in a trace written today.
TEST(Utf8Text, NlohmannsReplaceHandlerFollowsTheSameRule) {
    for (const Repair& c : ill_formed()) {
        const std::string dumped =
            nlohmann::json(c.bytes).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
        EXPECT_EQ(dumped, "\"" + valid_utf8(c.bytes) + "\"") << "from " << c.bytes;
    }
}

// ---- The writer stores UTF-8 ---------------------------------------------------------------

const std::string kLatin1 = "d\xE9j\xE0 vu \xA9";  // "déjà vu ©" in Latin-1
const std::string kRepaired = "d" + R + "j" + R + " vu " + R;

fbs::TraceHeaderT latin1_header() {
    fbs::TraceHeaderT h = test_header();
    h.device->name = "GPU " + kLatin1;
    h.device->driver_name = "driver " + kLatin1;
    h.device->driver_info = "info " + kLatin1;
    h.device->enabled_extensions = {"VK_KHR_ok", "VK_" + kLatin1};
    h.capture->application_name = "caf\xE9";
    h.capture->engine_name = "moteur " + kLatin1;
    h.capture->capture_tool = "tool " + kLatin1;
    h.capture->snapshot_policy = "policy " + kLatin1;
    return h;
}

// Every record kind with strings, each string Latin-1.
std::vector<fbs::RecordT> latin1_records() {
    std::vector<fbs::RecordT> out(6);
    fbs::CpuTimestampT t;
    t.label = "t " + kLatin1;
    out[0].body.Set(std::move(t));
    fbs::DebugLabelT l;
    l.text = "label " + kLatin1;
    out[1].body.Set(std::move(l));
    fbs::RayQueryCheckT c;
    c.label = "rays " + kLatin1;
    c.rays.push_back(fbs::TracedRay(0.f, 1.f, -5.f, 0.001f, 0.f, 0.f, 1.f, 1e30f, 1u, 0xffu));
    c.results.push_back(fbs::RayHitResult(1u, 5.25f, 7u, 2u, 31u, 0u, 0xfeu, 0.25f, 0.5f));
    out[2].body.Set(std::move(c));
    fbs::CaptureFindingT f;
    f.rule = "rule " + kLatin1;
    f.message = "message " + kLatin1;
    out[3].body.Set(std::move(f));
    fbs::CmdDrawT d;
    d.entry_point = "draw " + kLatin1;
    d.pipeline = 0x91;
    out[4].body.Set(std::move(d));
    fbs::CmdTraceRaysT rays;
    rays.entry_point = "rays " + kLatin1;
    rays.width = 640;
    out[5].body.Set(std::move(rays));
    return out;
}

void expect_repaired(const fbs::RecordT& r) {
    switch (r.body.type) {
    case fbs::RecordBody::CpuTimestamp:
        EXPECT_EQ(r.body.AsCpuTimestamp()->label, "t " + kRepaired);
        break;
    case fbs::RecordBody::DebugLabel:
        EXPECT_EQ(r.body.AsDebugLabel()->text, "label " + kRepaired);
        break;
    case fbs::RecordBody::RayQueryCheck:
        EXPECT_EQ(r.body.AsRayQueryCheck()->label, "rays " + kRepaired);
        EXPECT_EQ(r.body.AsRayQueryCheck()->results.size(), 1u);  // the rest of the record is kept
        break;
    case fbs::RecordBody::CaptureFinding:
        EXPECT_EQ(r.body.AsCaptureFinding()->rule, "rule " + kRepaired);
        EXPECT_EQ(r.body.AsCaptureFinding()->message, "message " + kRepaired);
        break;
    case fbs::RecordBody::CmdDraw:
        EXPECT_EQ(r.body.AsCmdDraw()->entry_point, "draw " + kRepaired);
        EXPECT_EQ(r.body.AsCmdDraw()->pipeline, 0x91u);
        break;
    case fbs::RecordBody::CmdTraceRays:
        EXPECT_EQ(r.body.AsCmdTraceRays()->entry_point, "rays " + kRepaired);
        EXPECT_EQ(r.body.AsCmdTraceRays()->width, 640u);
        break;
    default: ADD_FAILURE() << "unexpected record kind " << int(r.body.type);
    }
}

TEST(Utf8Writer, LatinOneNamesAndLabelsAreStoredAsUtf8WhicheverWayRecordsArrive) {
    const std::string path = temp_path("latin1.clt");
    TraceError e;
    auto w = TraceWriter::create(path, latin1_header(), {}, &e);
    ASSERT_TRUE(w) << e.message;
    const std::vector<fbs::RecordT> records = latin1_records();
    for (const fbs::RecordT& r : records) ASSERT_FALSE(w->append(r));  // the object API
    for (const fbs::RecordT& r : records) {  // a finished FlatBuffer, and a Record
        flatbuffers::FlatBufferBuilder b;
        b.Finish(fbs::Record::Pack(b, &r));
        ASSERT_FALSE(w->append_record_bytes(b.GetBufferPointer(), b.GetSize()));
        ASSERT_FALSE(w->append(fbs::GetRecord(b.GetBufferPointer())));
    }
    ASSERT_FALSE(w->finish());

    TraceError open_error;
    auto reader = TraceReader::open(path, &open_error);
    ASSERT_TRUE(reader) << open_error.message;
    const fbs::TraceHeader* h = reader->header();
    ASSERT_TRUE(h && h->device() && h->capture());
    EXPECT_EQ(h->device()->name()->str(), "GPU " + kRepaired);
    EXPECT_EQ(h->device()->driver_name()->str(), "driver " + kRepaired);
    EXPECT_EQ(h->device()->driver_info()->str(), "info " + kRepaired);
    ASSERT_EQ(h->device()->enabled_extensions()->size(), 2u);
    EXPECT_EQ(h->device()->enabled_extensions()->Get(0)->str(), "VK_KHR_ok");
    EXPECT_EQ(h->device()->enabled_extensions()->Get(1)->str(), "VK_" + kRepaired);
    EXPECT_EQ(h->capture()->application_name()->str(), "caf" + R);
    EXPECT_EQ(h->capture()->engine_name()->str(), "moteur " + kRepaired);
    EXPECT_EQ(h->capture()->capture_tool()->str(), "tool " + kRepaired);
    EXPECT_EQ(h->capture()->snapshot_policy()->str(), "policy " + kRepaired);

    ReadResult read = read_all(path);
    ASSERT_TRUE(read.opened);
    EXPECT_EQ(read.damage_count, 0u) << describe(read.damage);
    ASSERT_EQ(read.records.size(), 3 * records.size());
    for (const fbs::RecordT& r : read.records) expect_repaired(r);
}

TEST(Utf8Writer, Utf8NamesAreStoredAsGiven) {
    const std::string path = temp_path("utf8.clt");
    fbs::TraceHeaderT header = test_header();
    header.capture->application_name = "caf\xC3\xA9 \xF0\x9F\x98\x80";
    TraceError e;
    auto w = TraceWriter::create(path, header, {}, &e);
    ASSERT_TRUE(w) << e.message;
    fbs::RecordT r;
    fbs::DebugLabelT l;
    l.text = "\xE2\x82\xAC";
    r.body.Set(std::move(l));
    ASSERT_FALSE(w->append(r));
    ASSERT_FALSE(w->finish());
    ReadResult read = read_all(path);
    ASSERT_EQ(read.records.size(), 1u);
    EXPECT_EQ(read.records[0].body.AsDebugLabel()->text, "\xE2\x82\xAC");
    TraceError open_error;
    auto reader = TraceReader::open(path, &open_error);
    ASSERT_TRUE(reader) << open_error.message;
    EXPECT_EQ(reader->header()->capture()->application_name()->str(),
              "caf\xC3\xA9 \xF0\x9F\x98\x80");
}

// stored_text.cpp lists the schema's string fields by hand; a new one must be added there (and
// to the two tests above), which this count reminds of.
TEST(Utf8Writer, EveryStringFieldOfTheSchemaIsRepaired) {
    std::ifstream in(CLASTRACE_SCHEMA);
    ASSERT_TRUE(in) << CLASTRACE_SCHEMA;
    std::stringstream schema;
    schema << in.rdbuf();
    const std::string text = schema.str();
    const std::regex string_field(R"(\b\w+\s*:\s*\[?\s*string\s*\]?\s*[;=(])");
    const auto fields = std::distance(std::sregex_iterator(text.begin(), text.end(), string_field),
                                      std::sregex_iterator());
    // DeviceInfo 4, CaptureSettings 4, CpuTimestamp 1, DebugLabel 1, RayQueryCheck 1,
    // CaptureFinding 2, CmdDraw 1, CmdTraceRays 1
    EXPECT_EQ(fields, 15)
        << "a string field was added to or removed from trace.fbs: update stored_text.cpp";
}

}  // namespace
}  // namespace clastrace::traces::testing

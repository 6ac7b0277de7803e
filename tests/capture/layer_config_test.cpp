// SPDX-License-Identifier: Apache-2.0
#include "layer_config_env.h"

#include <gtest/gtest.h>

#include <string>
#include <thread>

#include <algorithm>
#include <mutex>

using namespace clastrace::capture;
using clastrace::capture::test::parse;

TEST(LayerConfig, DefaultsCaptureOnServeAuto) {
    LayerConfig c = parse({});
    EXPECT_TRUE(c.capture);
    EXPECT_EQ(c.serve, ServeMode::kAuto);
    EXPECT_EQ(c.zstd_level, 3);
    EXPECT_TRUE(c.submit_range.contains(0));
    EXPECT_TRUE(c.submit_range.contains(UINT64_MAX));
    EXPECT_TRUE(c.errors.empty());
}

TEST(LayerConfig, ReadsEveryVariable) {
    LayerConfig c = parse({{"CLASTRACE_CAPTURE", "0"},
                           {"CLASTRACE_SERVE", "1"},
                           {"CLASTRACE_OUTPUT", "/tmp/a.clt"},
                           {"CLASTRACE_SUBMIT_RANGE", "3-5"},
                           {"CLASTRACE_ZSTD_LEVEL", "19"},
                           {"CLASTRACE_LOG", "debug"}});
    EXPECT_FALSE(c.capture);
    EXPECT_EQ(c.serve, ServeMode::kOn);
    EXPECT_EQ(c.output_path, "/tmp/a.clt");
    EXPECT_FALSE(c.submit_range.contains(2));
    EXPECT_TRUE(c.submit_range.contains(3));
    EXPECT_TRUE(c.submit_range.contains(5));
    EXPECT_FALSE(c.submit_range.contains(6));
    EXPECT_EQ(c.zstd_level, 19);
    EXPECT_EQ(c.log, LogLevel::kDebug);
    EXPECT_TRUE(c.errors.empty());
}

TEST(LayerConfig, SubmitRangeForms) {
    EXPECT_EQ(parse({{"CLASTRACE_SUBMIT_RANGE", "7"}}).submit_range.first, 7u);
    EXPECT_EQ(parse({{"CLASTRACE_SUBMIT_RANGE", "7"}}).submit_range.last, 7u);
    EXPECT_EQ(parse({{"CLASTRACE_SUBMIT_RANGE", "4-"}}).submit_range.last, UINT64_MAX);
    EXPECT_EQ(parse({{"CLASTRACE_SERVE", "0"}}).serve, ServeMode::kOff);
    EXPECT_EQ(parse({{"CLASTRACE_SERVE", "auto"}}).serve, ServeMode::kAuto);
}

TEST(LayerConfig, BadValuesKeepDefaultsAndNameTheVariable) {
    LayerConfig c = parse({{"CLASTRACE_ZSTD_LEVEL", "99"},
                           {"CLASTRACE_SUBMIT_RANGE", "9-2"},
                           {"CLASTRACE_SERVE", "maybe"},
                           {"CLASTRACE_CAPTURE", ""},
                           {"CLASTRACE_LOG", "loud"}});
    EXPECT_EQ(c.zstd_level, 3);
    EXPECT_EQ(c.submit_range.first, 0u);
    EXPECT_EQ(c.serve, ServeMode::kAuto);
    EXPECT_TRUE(c.capture);
    ASSERT_EQ(c.errors.size(), 5u);
    EXPECT_NE(c.errors[0].find("CLASTRACE_CAPTURE=''"), std::string::npos);
    EXPECT_NE(c.errors[1].find("CLASTRACE_SERVE='maybe'"), std::string::npos);
    EXPECT_NE(c.errors[2].find("CLASTRACE_SUBMIT_RANGE='9-2'"), std::string::npos);
    EXPECT_NE(c.errors[3].find("CLASTRACE_ZSTD_LEVEL='99'"), std::string::npos);
    EXPECT_NE(c.errors[4].find("CLASTRACE_LOG='loud'"), std::string::npos);
}

TEST(LayerConfig, RejectsOverflowingNumbers) {
    LayerConfig c = parse(
        {{"CLASTRACE_SUBMIT_RANGE", "99999999999999999999999"}, {"CLASTRACE_ZSTD_LEVEL", "-101"}});
    EXPECT_EQ(c.errors.size(), 2u);
    EXPECT_EQ(c.submit_range.first, 0u);
    EXPECT_EQ(c.zstd_level, 3);
}

TEST(LayerConfig, ZstdFastLevelsAreNegative) {
    EXPECT_EQ(parse({{"CLASTRACE_ZSTD_LEVEL", "-5"}}).zstd_level, -5);
    EXPECT_EQ(parse({{"CLASTRACE_ZSTD_LEVEL", "-100"}}).zstd_level, -100);
    for (const char* bad : {"0", "-0", "-", "--1", "23"}) {
        LayerConfig c = parse({{"CLASTRACE_ZSTD_LEVEL", bad}});
        EXPECT_EQ(c.zstd_level, 3) << bad;
        EXPECT_EQ(c.errors.size(), 1u) << bad;
    }
}

namespace {

// A switch on by default: "0" turns it off, "1" on; another value keeps the default and is
// named in one error.
void expect_on_by_default(const char* variable, bool LayerConfig::*setting, const char* bad) {
    EXPECT_TRUE(parse({}).*setting);
    EXPECT_FALSE(parse({{variable, "0"}}).*setting);
    EXPECT_TRUE(parse({{variable, "1"}}).*setting);
    LayerConfig config = parse({{variable, bad}});
    EXPECT_TRUE(config.*setting);
    ASSERT_EQ(config.errors.size(), 1u);
    EXPECT_NE(config.errors[0].find(std::string(variable) + "='" + bad + "'"), std::string::npos)
        << config.errors[0];
}

}  // namespace

TEST(LayerConfig, TimestampsOnByDefaultAndSwitchedByZeroOrOne) {
    expect_on_by_default("CLASTRACE_TIMESTAMPS", &LayerConfig::timestamps, "sometimes");
}

TEST(LayerConfig, DeltaContentsOnByDefaultAndSwitchedByZeroOrOne) {
    expect_on_by_default("CLASTRACE_DELTA_CONTENTS", &LayerConfig::delta_contents, "xor");
}

TEST(LayerConfig, HostWritesGuardByDefaultHashGuardOrOff) {
    EXPECT_TRUE(parse({}).host_writes);
    EXPECT_TRUE(parse({}).host_write_guard);
    for (const char* on : {"guard", "1"}) {
        const LayerConfig c = parse({{"CLASTRACE_HOST_WRITES", on}});
        EXPECT_TRUE(c.host_writes && c.host_write_guard) << on;
    }
    const LayerConfig hash = parse({{"CLASTRACE_HOST_WRITES", "hash"}});
    EXPECT_TRUE(hash.host_writes);
    EXPECT_FALSE(hash.host_write_guard);
    EXPECT_FALSE(parse({{"CLASTRACE_HOST_WRITES", "0"}}).host_writes);
    const LayerConfig bad = parse({{"CLASTRACE_HOST_WRITES", "pages"}});
    EXPECT_TRUE(bad.host_writes && bad.host_write_guard);
    ASSERT_EQ(bad.errors.size(), 1u);
    EXPECT_NE(bad.errors[0].find("CLASTRACE_HOST_WRITES"), std::string::npos);
}

TEST(LayerConfig, DeviceAddressWritesCheapByDefaultOffCheapOrExact) {
    EXPECT_TRUE(parse({}).mark_device_address_writers);
    EXPECT_FALSE(parse({}).exact_device_address_writes);
    EXPECT_FALSE(parse({{"CLASTRACE_DEVICE_ADDRESS_WRITES", "off"}}).mark_device_address_writers);
    EXPECT_TRUE(parse({{"CLASTRACE_DEVICE_ADDRESS_WRITES", "cheap"}}).mark_device_address_writers);
    // exact marks as cheap does (draws stay cheap) and compares around marked dispatches.
    LayerConfig exact = parse({{"CLASTRACE_DEVICE_ADDRESS_WRITES", "exact"}});
    EXPECT_TRUE(exact.errors.empty());
    EXPECT_TRUE(exact.mark_device_address_writers);
    EXPECT_TRUE(exact.exact_device_address_writes);
    LayerConfig bad = parse({{"CLASTRACE_DEVICE_ADDRESS_WRITES", "precise"}});
    EXPECT_TRUE(bad.mark_device_address_writers);  // the default is kept
    EXPECT_FALSE(bad.exact_device_address_writes);
    ASSERT_EQ(bad.errors.size(), 1u);
    EXPECT_NE(bad.errors[0].find("CLASTRACE_DEVICE_ADDRESS_WRITES='precise'"), std::string::npos);
}

TEST(LayerConfig, BackgroundCpusSpareByDefaultAppOrAList) {
    EXPECT_EQ(parse({}).background_cpus.mode, BackgroundCpus::Mode::kSpare);
    EXPECT_EQ(parse({{"CLASTRACE_BACKGROUND_CPUS", "app"}}).background_cpus.mode,
              BackgroundCpus::Mode::kApp);
    LayerConfig listed = parse({{"CLASTRACE_BACKGROUND_CPUS", "6-7,12,7"}});
    EXPECT_EQ(listed.background_cpus.mode, BackgroundCpus::Mode::kList);
    EXPECT_EQ(listed.background_cpus.list, (std::vector<unsigned>{6, 7, 12}));
    for (const char* bad : {"", "idle", "3-1", "1,", ",1", "-2", "4096", "1-2-3", "a"}) {
        LayerConfig c = parse({{"CLASTRACE_BACKGROUND_CPUS", bad}});
        EXPECT_EQ(c.background_cpus.mode, BackgroundCpus::Mode::kSpare) << bad;
        ASSERT_EQ(c.errors.size(), 1u) << bad;
        EXPECT_NE(c.errors[0].find("CLASTRACE_BACKGROUND_CPUS='" + std::string(bad) + "'"),
                  std::string::npos);
    }
}

TEST(BackgroundCpus, ListsParseAndFoldBack) {
    EXPECT_EQ(parse_cpu_list("0-3,8"), (std::vector<unsigned>{0, 1, 2, 3, 8}));
    EXPECT_EQ(parse_cpu_list("5"), (std::vector<unsigned>{5}));
    EXPECT_EQ(parse_cpu_list("4095"), (std::vector<unsigned>{4095}));
    EXPECT_EQ(format_cpu_list({0, 1, 2, 3, 8}), "0-3,8");
    EXPECT_EQ(format_cpu_list({1, 3, 4}), "1,3-4");
    EXPECT_EQ(format_cpu_list({}), "none");
    EXPECT_EQ(format_cpu_list(*parse_cpu_list("0-1,6-15")), "0-1,6-15");
}

TEST(BackgroundCpus, SpareIsTheOnlineCpusTheApplicationLacks) {
    const std::vector<unsigned> online = *parse_cpu_list("0-15");
    const BackgroundCpus spare;
    EXPECT_EQ(format_cpu_list(background_cpus_for(spare, online, *parse_cpu_list("2-5"))),
              "0-1,6-15");
    EXPECT_TRUE(
        background_cpus_for(spare, online, online).empty());  // nothing spare: stay with the app
    EXPECT_TRUE(background_cpus_for(spare, online, {}).empty());  // the app's CPUs unknown
    // CPUs the kernel keeps apart (isolcpus, nohz_full) are someone else's.
    EXPECT_EQ(format_cpu_list(
                  background_cpus_for(spare, online, *parse_cpu_list("2-5"), {12, 13, 14, 15})),
              "0-1,6-11");
    EXPECT_TRUE(
        background_cpus_for(spare, online, *parse_cpu_list("0-11"), {12, 13, 14, 15}).empty());
    EXPECT_TRUE(
        background_cpus_for({BackgroundCpus::Mode::kApp, {}}, online, *parse_cpu_list("2-5"))
            .empty());
    EXPECT_EQ(background_cpus_for({BackgroundCpus::Mode::kList, {9}}, online, online),
              (std::vector<unsigned>{9}));
}

// The SMT siblings of the application's CPUs (2-5 on cores shared with 10-13) are left out while
// other CPUs remain, and taken when only they are spare; `app` and a list ignore them.
TEST(BackgroundCpus, SpareLeavesOutTheApplicationsSmtSiblingsWhileOtherCoresRemain) {
    const std::vector<unsigned> online = *parse_cpu_list("0-15");
    const std::vector<unsigned> app = *parse_cpu_list("2-5");
    const std::vector<unsigned> siblings = *parse_cpu_list("10-13");
    const BackgroundCpus spare;
    EXPECT_EQ(format_cpu_list(background_cpus_for(spare, online, app, {}, siblings)),
              "0-1,6-9,14-15");
    EXPECT_EQ(format_cpu_list(
                  background_cpus_for(spare, online, app, {0, 1, 6, 7, 8, 9, 14, 15}, siblings)),
              "10-13");  // only siblings left: better than the application's own CPUs
    EXPECT_EQ(format_cpu_list(background_cpus_for(spare, *parse_cpu_list("0-7"),
                                                  *parse_cpu_list("0-3"), {}, {4, 5, 6, 7})),
              "4-7");
    EXPECT_TRUE(
        background_cpus_for({BackgroundCpus::Mode::kApp, {}}, online, app, {}, siblings).empty());
    EXPECT_EQ(background_cpus_for({BackgroundCpus::Mode::kList, {10}}, online, app, {}, siblings),
              (std::vector<unsigned>{10}));
}

// This machine's topology: a CPU's siblings never include the CPUs asked about, and every CPU
// is a sibling of none once all are asked about.
TEST(BackgroundCpus, SmtSiblingsAreOtherCpusOfTheSameCores) {
    const std::vector<unsigned> online = online_cpus();
    if (online.empty()) GTEST_SKIP() << "no /sys/devices/system/cpu/online";
    EXPECT_TRUE(smt_siblings(online).empty());
    const std::vector<unsigned> first{online[0]};
    for (unsigned s : smt_siblings(first)) {
        EXPECT_NE(s, online[0]);
        EXPECT_TRUE(std::binary_search(online.begin(), online.end(), s)) << s;
    }
}

// The sink places its thread from the creating thread, before that thread has run: the
// affinity read back is the one set, whatever the new thread is doing.
TEST(BackgroundCpus, AnotherThreadIsPlacedWithoutWaitingForIt) {
    const std::vector<unsigned> mine = calling_thread_cpus();
    ASSERT_FALSE(mine.empty());
    std::mutex gate;
    std::unique_lock hold(gate);
    std::thread blocked([&] { std::lock_guard wait(gate); });
    EXPECT_TRUE(place_thread(blocked.native_handle(), {mine.back()}));
    EXPECT_EQ(thread_cpus(blocked.native_handle()), std::vector<unsigned>{mine.back()});
    EXPECT_EQ(calling_thread_cpus(), mine);  // the creator stays where it was
    hold.unlock();
    blocked.join();
}

TEST(BackgroundCpus, TheCallingThreadCanBePlacedOnItsOwnCpusAndBack) {
    const std::vector<unsigned> mine = calling_thread_cpus();
    ASSERT_FALSE(mine.empty());
    EXPECT_TRUE(place_calling_thread({mine.front()}));
    EXPECT_EQ(calling_thread_cpus(), std::vector<unsigned>{mine.front()});
    EXPECT_TRUE(place_calling_thread(mine));
    EXPECT_EQ(calling_thread_cpus(), mine);
    EXPECT_FALSE(place_calling_thread({}));
    // A set the kernel refuses (no such CPU here) leaves the thread where it was.
    if (mine.back() < 4095) {
        EXPECT_FALSE(place_calling_thread({4095}));
        EXPECT_EQ(calling_thread_cpus(), mine);
    }
}

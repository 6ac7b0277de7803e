// SPDX-License-Identifier: Apache-2.0
// The page guard of the host-write watch (capture/src/page_guard.h) on anonymous memory: what a
// write to a watched page leaves behind, from this thread and another, what watching refuses,
// and that faults on pages it does not hold still reach the handler installed before or after it.
#include "page_guard.h"

#include <gtest/gtest.h>

#include <csignal>
#include <cstring>
#include <thread>
#include <vector>

#include <fcntl.h>
#include <sys/mman.h>
#include <unistd.h>

namespace {

using clastrace::capture::PageGuard;

class PageGuardTest : public ::testing::Test {
protected:
    void SetUp() override {
        guard = PageGuard::instance();
        ASSERT_NE(guard, nullptr);
        page = guard->page_size();
        void* m =
            mmap(nullptr, 4 * page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        ASSERT_NE(m, MAP_FAILED);
        memory = static_cast<uint8_t*>(m);
        std::memset(memory, 7, 4 * page);
    }
    // Pages left read-only past their watchers are forgotten before the memory goes, as
    // vkFreeMemory does: a later mapping at these addresses is not taken for protected.
    void TearDown() override {
        guard->forget_memory(at(0), 4 * page);
        munmap(memory, 4 * page);
    }
    uintptr_t at(size_t i) const { return reinterpret_cast<uintptr_t>(memory + i * page); }
    // Pages first .. first + count - 1, as the guard takes them.
    std::vector<uintptr_t> pages(size_t first, size_t count = 1) const {
        std::vector<uintptr_t> out;
        for (size_t i = first; i < first + count; ++i) out.push_back(at(i));
        return out;
    }

    PageGuard* guard = nullptr;
    size_t page = 0;
    uint8_t* memory = nullptr;
};

TEST_F(PageGuardTest, AWriteLandsAndThePageKeepsItsBeforeImage) {
    const uint64_t faults = guard->counts().faults;
    ASSERT_TRUE(guard->watch(pages(1, 2), false));
    EXPECT_EQ(guard->before_image(at(1)), nullptr);
    memory[page + 10] = 42;
    EXPECT_EQ(memory[page + 10], 42);
    const uint8_t* before = guard->before_image(at(1));
    ASSERT_NE(before, nullptr);
    EXPECT_EQ(before[10], 7);
    EXPECT_EQ(guard->before_image(at(2)), nullptr);  // the other page was not written
    EXPECT_EQ(guard->counts().faults, faults + 1);
    memory[page + 11] = 43;  // writable now: no second fault
    EXPECT_EQ(guard->counts().faults, faults + 1);
    guard->unwatch(pages(1, 2));
    EXPECT_EQ(guard->before_image(at(1)), nullptr);
    memory[2 * page] = 1;  // unwatched (resting): the write goes through, nothing kept
    EXPECT_EQ(memory[2 * page], 1);
    EXPECT_EQ(guard->before_image(at(2)), nullptr);
    EXPECT_EQ(guard->counts().faults, faults + 1);
}

// An unwritten page keeps its protection past its last watcher: the next watch adopts it without
// an mprotect, a write after the unwatch costs one fault and no before-image, and only that page
// is protected again by the next watch.
TEST_F(PageGuardTest, AnUnwrittenPageStaysReadOnlyForTheNextWatch) {
    ASSERT_TRUE(guard->watch(pages(0, 3), false));
    memory[0] = 1;  // page 0 written while watched
    guard->unwatch(pages(0, 3));
    const PageGuard::Counts rested = guard->counts();
    ASSERT_TRUE(guard->watch(pages(1, 2), false));  // pages 1 and 2 rested read-only
    EXPECT_EQ(guard->counts().protect_calls, rested.protect_calls);
    memory[page] = 2;  // still protected: the watch sees it
    ASSERT_NE(guard->before_image(at(1)), nullptr);
    EXPECT_EQ(guard->before_image(at(1))[0], 7);
    EXPECT_EQ(guard->counts().faults, rested.faults + 1);
    guard->unwatch(pages(1, 2));
    memory[2 * page] = 3;  // resting: one fault, not a watched write
    EXPECT_EQ(memory[2 * page], 3);
    EXPECT_EQ(guard->counts().resting_faults, rested.resting_faults + 1);
    EXPECT_EQ(guard->counts().faults, rested.faults + 1);
    EXPECT_EQ(guard->before_image(at(2)), nullptr);
    const PageGuard::Counts again = guard->counts();
    ASSERT_TRUE(guard->watch(pages(0, 3), false));  // pages 0..2 written since: protected anew
    EXPECT_EQ(guard->counts().protected_pages, again.protected_pages + 3);
    memory[2 * page + 1] = 4;
    ASSERT_NE(guard->before_image(at(2)), nullptr);
    EXPECT_EQ(guard->before_image(at(2))[0], 3);
    guard->unwatch(pages(0, 3));
}

// A frame loop's page: watched at each submission and rewritten by the host after each wait. Its
// writes while resting make it hot for ever longer (8 unwatches, then 16, 32, 64...), so 100
// frames cost it 4 faults, not one in every 9 frames, and every write still lands; a write while
// watched is still seen in every frame.
TEST_F(PageGuardTest, APageRewrittenAfterEveryWaitFaultsLessAndLessOften) {
    const PageGuard::Counts before = guard->counts();
    for (int frame = 0; frame < 100; ++frame) {
        ASSERT_TRUE(guard->watch(pages(1, 1), false));
        if (frame % 10 == 5) {  // a racing write: seen, with the page as it was
            memory[page + 1] = uint8_t(frame);
            ASSERT_NE(guard->before_image(at(1)), nullptr);
            EXPECT_EQ(guard->before_image(at(1))[0], uint8_t(frame - 1));
        }
        guard->unwatch(pages(1, 1));
        memory[page] = uint8_t(frame);
        ASSERT_EQ(memory[page], uint8_t(frame));
    }
    EXPECT_EQ(guard->counts().resting_faults, before.resting_faults + 4);
    EXPECT_EQ(guard->counts().faults, before.faults + 10);
}

// With resting off (CLASTRACE_GUARD_REST=0) no page stays read-only past its last watcher: a
// system call may write the page after the wait (read(2) into it would fail with EFAULT on a
// read-only page), and the next watch protects it again.
TEST_F(PageGuardTest, WithRestingOffAnUnwatchedPageIsWritableAtOnce) {
    guard->set_resting(false);
    ASSERT_TRUE(guard->watch(pages(1, 2), false));
    const PageGuard::Counts watched = guard->counts();
    guard->unwatch(pages(1, 2));
    EXPECT_EQ(guard->counts().unprotected_pages, watched.unprotected_pages + 2);
    memory[page] = 9;
    memory[2 * page] = 9;
    EXPECT_EQ(guard->counts().faults, watched.faults);
    EXPECT_EQ(guard->counts().resting_faults, watched.resting_faults);
    ASSERT_TRUE(guard->watch(pages(1, 1), false));
    EXPECT_EQ(guard->counts().protected_pages, watched.protected_pages + 1);
    guard->unwatch(pages(1, 1));
    guard->set_resting(true);
}

// Memory going away: its resting pages become writable without a fault, and the next watch of
// those addresses protects them again.
TEST_F(PageGuardTest, ForgottenMemoryIsWritableAndProtectedAfresh) {
    ASSERT_TRUE(guard->watch(pages(0, 4), false));
    guard->unwatch(pages(0, 4));
    const PageGuard::Counts rested = guard->counts();
    guard->forget_memory(at(1), 2 * page);  // pages 1 and 2
    memory[page] = 5;
    memory[2 * page] = 5;
    EXPECT_EQ(guard->counts().resting_faults, rested.resting_faults);
    EXPECT_EQ(guard->counts().unprotected_pages, rested.unprotected_pages + 2);
    memory[3 * page] = 6;  // not forgotten: still resting
    EXPECT_EQ(guard->counts().resting_faults, rested.resting_faults + 1);
    ASSERT_TRUE(guard->watch(pages(1, 1), false));
    EXPECT_EQ(guard->counts().protected_pages, rested.protected_pages + 1);
    memory[page] = 8;
    EXPECT_NE(guard->before_image(at(1)), nullptr);
    guard->unwatch(pages(1, 1));
}

TEST_F(PageGuardTest, AnotherThreadsWriteIsSeenToo) {
    ASSERT_TRUE(guard->watch(pages(0, 1), true));
    std::thread([&] { std::memset(memory + 100, 9, 50); }).join();
    const uint8_t* before = guard->before_image(at(0));
    ASSERT_NE(before, nullptr);
    EXPECT_EQ(before[100], 7);
    EXPECT_EQ(memory[100], 9);
    guard->unwatch(pages(0, 1));
}

TEST_F(PageGuardTest, AWrittenPageIsRefusedUntilItsWatchersAreGone) {
    ASSERT_TRUE(guard->watch(pages(3, 1), false));
    ASSERT_TRUE(guard->watch(pages(3, 1), false));  // a second watcher of the same page
    memory[3 * page] = 1;
    EXPECT_FALSE(guard->watch(pages(3, 1), false));  // its reference is gone
    guard->unwatch(pages(3, 1));
    EXPECT_NE(guard->before_image(at(3)), nullptr);  // still one watcher
    guard->unwatch(pages(3, 1));
    EXPECT_TRUE(guard->watch(pages(3, 1), false));  // protected afresh
    EXPECT_EQ(guard->before_image(at(3)), nullptr);
    guard->unwatch(pages(3, 1));
}

TEST_F(PageGuardTest, MprotectRefusingIsReportedAndNothingStaysWatched) {
    const uint64_t refused = guard->counts().refused;
    munmap(memory + 2 * page, page);  // a hole: mprotect over it fails with ENOMEM
    EXPECT_FALSE(guard->watch(pages(1, 3), false));
    EXPECT_EQ(guard->counts().refused, refused + 1);
    memory[page] = 5;  // the page protected before the hole is writable again
    EXPECT_EQ(guard->before_image(at(1)), nullptr);
    mmap(memory + 2 * page, page, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_FIXED,
         -1, 0);
}

TEST_F(PageGuardTest, AProbeWritesThroughAndLeavesThePageAsItWas) {
    const PageGuard::Counts before = guard->counts();
    EXPECT_TRUE(guard->probe(at(2)));
    EXPECT_EQ(memory[2 * page], 7);  // an atomic add of 0
    memory[2 * page] = 8;            // writable, unwatched
    EXPECT_EQ(guard->before_image(at(2)), nullptr);
    EXPECT_EQ(guard->counts().faults, before.faults);  // the probe's fault is not a host write
    EXPECT_EQ(guard->counts().refused, before.refused);
}

// A shared mapping of a file opened read-only cannot be made writable: the probe's write faults,
// the handler cannot let it through, and the probe says so instead of the process dying.
TEST_F(PageGuardTest, AProbeOfAMappingThatStaysReadOnlyFails) {
    char name[] = "/tmp/clastrace_page_guard_XXXXXX";
    const int fd = mkstemp(name);
    ASSERT_GE(fd, 0);
    std::vector<uint8_t> bytes(page, 3);
    ASSERT_EQ(write(fd, bytes.data(), page), ssize_t(page));
    const int read_only = open(name, O_RDONLY);
    unlink(name);
    close(fd);
    ASSERT_GE(read_only, 0);
    void* m = mmap(nullptr, page, PROT_READ, MAP_SHARED, read_only, 0);
    close(read_only);
    ASSERT_NE(m, MAP_FAILED);
    const uint64_t refused = guard->counts().refused;
    EXPECT_FALSE(guard->probe(reinterpret_cast<uintptr_t>(m)));
    EXPECT_EQ(guard->counts().refused, refused + 1);
    EXPECT_EQ(static_cast<uint8_t*>(m)[0], 3);
    munmap(m, page);
}

uint8_t* own_page = nullptr;
int own_faults = 0;

void own_handler(int, siginfo_t* info, void*) {
    if (info->si_addr != own_page) std::abort();
    mprotect(own_page, 4096, PROT_READ | PROT_WRITE);
    ++own_faults;
}

// The application's handler, installed after the guard's, comes second again at the next watch,
// and still gets the faults that are its own while pages are guarded.
TEST_F(PageGuardTest, TheApplicationsHandlerStillGetsItsFaults) {
    own_page =
        static_cast<uint8_t*>(mmap(nullptr, page, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0));
    ASSERT_NE(own_page, MAP_FAILED);
    struct sigaction mine {
    }, before{};
    mine.sa_sigaction = own_handler;
    mine.sa_flags = SA_SIGINFO;
    sigemptyset(&mine.sa_mask);
    ASSERT_EQ(sigaction(SIGSEGV, &mine, &before), 0);
    ASSERT_TRUE(guard->watch(pages(0, 1), false));  // takes SIGSEGV first again
    memory[0] = 3;                                  // the guard's
    own_page[0] = 1;                                // the application's
    EXPECT_EQ(own_faults, 1);
    EXPECT_NE(guard->before_image(at(0)), nullptr);
    guard->unwatch(pages(0, 1));
    munmap(own_page, page);
}

}  // namespace

// How the `rolamos` program sets up glibc's malloc before any work.
//
// Frames, pyramids, warps and tiles are megabytes each, allocated and freed at every frame. What
// costs is not the allocation but the first touch of each page: on the virtual machines vehicles
// and clusters run, a page fault costs ~10 us, and mapping 60 frames of 1292 x 964 touched ~80,000
// 4 KiB pages, a sixth of its CPU time (bench/RESULTS.md, session 47). Backed by 2 MiB transparent
// huge pages the same heap takes ~2,000 faults. glibc's malloc asks the kernel for them when the
// tunable glibc.malloc.hugetlb=1 is set, and reads tunables only when a program starts: so the
// program starts itself once more with it, before doing anything.
#pragma once

#include <optional>
#include <string>

namespace rolamos {

// GLIBC_TUNABLES with glibc.malloc.hugetlb=1 added to `current` (the variable's value, "" when
// unset); nullopt when `current` already sets glibc.malloc.hugetlb, to any value: the user's
// choice stands (glibc.malloc.hugetlb=0 turns huge pages off).
std::optional<std::string> TunablesWithHugePageHeap(const std::string& current);

// True when the kernel gives transparent huge pages only where asked (`madvise` in
// /sys/kernel/mm/transparent_hugepage/enabled, `thp_enabled`): the one mode where the tunable
// changes anything.
bool HugePagesOnRequest(const std::string& thp_enabled);

// Runs this program again, same pid, arguments and environment, with TunablesWithHugePageHeap()
// in GLIBC_TUNABLES, when that changes anything (Linux with madvise-mode huge pages, the tunable
// not set yet). Call first in main, before any thread starts. Returns when it does not re-run.
void RestartWithHugePageHeap(char** argv);

// One heap for all threads, kept between frames: M_ARENA_MAX 1 (per-thread heaps live in 64 MiB
// mappings that are unmapped when they empty, and touched again page by page), and no freeing
// back to the kernel below 128 MiB nor mapping of blocks under 64 MiB.
void KeepOneHeap();

}  // namespace rolamos

// File helpers for atomic writes: write to a temporary sibling, then rename into place.
#pragma once

#include <string>

namespace rolamos {

// A unique temporary name next to `path` (same directory, so rename is atomic).
std::string TemporarySibling(const std::string& path);
// Writes `text` to `path` atomically (temporary file, fsync, rename). Throws Error. Without
// `durable`, no fsync: readers never see a partial file, but a crash may lose the newest version
// (files rewritten several times a second, such as a live run's status).
void WriteFileAtomic(const std::string& path, const std::string& text, bool durable = true);
// Reads a whole (small) file; throws Error naming it when missing or larger than `max_bytes`.
std::string ReadSmallFile(const std::string& path, size_t max_bytes = 64u << 20);
// Renames, throwing Error with both names on failure.
void RenameFile(const std::string& from, const std::string& to);
std::string ToLower(std::string s);
std::string ToUpper(std::string s);
std::string Extension(const std::string& path);  // lower-case, with the dot
// Names in the order a person (and a camera's counter) numbers them: runs of digits compare by
// their value, so frame9 comes before frame10 (`ffmpeg -i dive.mp4 frame%d.jpg` writes such names);
// the rest as bytes. Names equal but for leading zeros fall back to byte order.
bool NaturalLess(const std::string& a, const std::string& b);

}  // namespace rolamos

#include "compose/tile_journal.h"

#include <fcntl.h>
#include <linux/falloc.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "rolamos/error.hpp"
#include "raster/tiff_file.h"
#include "raster/tiff_tags.h"
#include "util/files.h"

namespace rolamos {

namespace fs = std::filesystem;

namespace {

constexpr const char* kMagic = "rolamos-compose-journal 1";

void WriteAll(int fd, const void* data, size_t size, uint64_t offset, const std::string& where) {
  const auto* p = static_cast<const uint8_t*>(data);
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::pwrite(fd, p + done, size - done, static_cast<off_t>(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) Fail(where, std::string("cannot write: ") + std::strerror(errno));
    done += static_cast<size_t>(n);
  }
}

void AppendAll(int fd, const std::string& text, const std::string& where) {
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) Fail(where, std::string("cannot write: ") + std::strerror(errno));
    done += static_cast<size_t>(n);
  }
}

}  // namespace

std::string FingerprintHex(const std::string& text) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  char out[17];
  std::snprintf(out, sizeof out, "%016" PRIx64, h);
  return out;
}

namespace {

// A part's two files: tiles.bin + journal.txt, or tiles.PART.bin + journal.PART.txt.
std::string PartFile(const std::string& dir, const char* stem, const std::string& part, const char* ext) {
  return (fs::path(dir) / (std::string(stem) + (part.empty() ? "" : "." + part) + ext)).string();
}

}  // namespace

TileJournal::TileJournal(const std::string& dir, const std::string& fingerprint, bool restart, const std::string& part)
    : dir_(dir), data_path_(PartFile(dir, "tiles", part, ".bin")),
      journal_path_(PartFile(dir, "journal", part, ".txt")) {
  std::error_code ec;
  if (restart && fs::exists(journal_path_, ec)) discarded_ = "a restart was asked for";
  if (restart) fs::remove_all(dir, ec);
  fs::create_directories(dir, ec);
  if (ec) Fail(dir, "cannot create the folder for the partial mosaic: " + ec.message());
  Load(fingerprint);
  data_fd_ = ::open(data_path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  journal_fd_ = ::open(journal_path_.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (data_fd_ < 0 || journal_fd_ < 0) Fail(dir, std::string("cannot open the partial mosaic: ") + std::strerror(errno));
  parts_[0].data_fd = data_fd_;
  struct stat st {};
  if (::fstat(journal_fd_, &st) == 0 && st.st_size == 0)
    AppendAll(journal_fd_, std::string(kMagic) + " " + fingerprint + "\n", journal_path_);
  // New tiles go after everything already in the data file, committed or not.
  if (::fstat(data_fd_, &st) == 0) data_end_ = static_cast<uint64_t>(st.st_size);
}

TileJournal::~TileJournal() {
  for (auto& p : parts_)
    if (p.data_fd >= 0 && p.data_fd != data_fd_) ::close(p.data_fd);
  if (data_fd_ >= 0) ::close(data_fd_);
  if (journal_fd_ >= 0) ::close(journal_fd_);
}

void TileJournal::Load(const std::string& fingerprint) {
  parts_.push_back({data_path_, journal_path_, -1});
  std::error_code ec;
  // Other writers' parts: every journal*.txt but this one's.
  std::vector<std::string> others;
  for (const auto& e : fs::directory_iterator(dir_, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("journal", 0) == 0 && e.path().extension() == ".txt" && e.path().string() != journal_path_)
      others.push_back(e.path().string());
  }
  std::sort(others.begin(), others.end());
  std::string why;
  if (!fs::exists(journal_path_, ec)) {
    fs::remove(data_path_, ec);
  } else if (!LoadPart(0, fingerprint, &why)) {
    if (discarded_.empty()) discarded_ = why;
    done_.clear();
    levels_.clear();
    fs::remove(journal_path_, ec);
    fs::remove(data_path_, ec);
  }
  for (const auto& j : others) {
    const std::string name = fs::path(j).filename().string();  // journal[.PART].txt
    const std::string part = name.size() > 12 ? name.substr(8, name.size() - 12) : "";
    Part p{PartFile(dir_, "tiles", part, ".bin"), j, -1};
    p.data_fd = ::open(p.data_path.c_str(), O_RDONLY | O_CLOEXEC);
    if (p.data_fd < 0) continue;  // nothing written yet
    parts_.push_back(p);
    // Records of a part are kept aside until the whole part is known good.
    const auto done_before = done_;
    const auto levels_before = levels_;
    if (!LoadPart(static_cast<int>(parts_.size() - 1), fingerprint, &why)) {
      done_ = done_before;
      levels_ = levels_before;
      stale_parts_.push_back(name + ": " + why);
      ::close(parts_.back().data_fd);
      parts_.pop_back();
    }
  }
}

bool TileJournal::LoadPart(int part, const std::string& fingerprint, std::string* why) {
  const Part& p = parts_[static_cast<size_t>(part)];
  std::string text;
  try {
    text = ReadSmallFile(p.journal_path, size_t(1) << 30);
  } catch (const Error&) {
    text.clear();  // unreadable: treated as foreign below
  }
  std::istringstream in(text);
  std::string header;
  std::getline(in, header);
  if (header != std::string(kMagic) + " " + fingerprint) {
    *why = header.rfind(kMagic, 0) == 0 ? "the partial mosaic there was for other patches or options"
                                        : "the partial mosaic there was unreadable";
    return false;
  }
  struct stat st {};
  const uint64_t data_size = ::stat(p.data_path.c_str(), &st) == 0 ? uint64_t(st.st_size) : 0;
  std::string line;
  while (std::getline(in, line)) {
    if (line == "assembling") {
      // WriteTiff frees the tiles it has copied: a run that died then left holes, not tiles.
      *why = "the interrupted run was already writing mosaic.tif, whose tiles it had freed";
      return false;
    }
    // "chunk ID N level,index,offset,size ... end": a line cut short by a crash has no "end".
    if (line.size() < 4 || line.compare(line.size() - 4, 4, " end") != 0) continue;
    std::istringstream l(line);
    std::string word;
    long long chunk = 0, n = 0;
    if (!(l >> word >> chunk >> n) || word != "chunk" || n < 0) continue;
    std::vector<JournalTile> tiles;
    bool ok = true;
    for (long long i = 0; i < n && ok; ++i) {
      JournalTile t;
      char c1, c2, c3;
      ok = static_cast<bool>(l >> t.level >> c1 >> t.index >> c2 >> t.offset >> c3 >> t.size) &&
           c1 == ',' && c2 == ',' && c3 == ',' && t.level >= -1 && t.level < 64 && t.index >= 0 &&
           t.offset + t.size <= data_size;
      tiles.push_back(t);
    }
    if (!ok) continue;
    for (const auto& t : tiles) Record(part, t);
    done_.insert(chunk);
  }
  return true;
}

void TileJournal::Record(int part, const JournalTile& t) {
  const size_t k = static_cast<size_t>(t.level + 1);
  if (levels_.size() <= k) levels_.resize(k + 1);
  auto& v = levels_[k];
  if (v.size() <= static_cast<size_t>(t.index)) v.resize(static_cast<size_t>(t.index) + 1);
  v[static_cast<size_t>(t.index)] = {part, t.offset, t.size};
}

JournalTile TileJournal::Put(int level, long long index, const void* data, size_t size) {
  JournalTile t;
  t.level = level;
  t.index = index;
  t.size = static_cast<uint32_t>(size);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    t.offset = data_end_;
    data_end_ += size;
  }
  WriteAll(data_fd_, data, size, t.offset, data_path_);
  return t;
}

void TileJournal::Commit(long long chunk, const std::vector<JournalTile>& tiles) {
  std::string line = "chunk " + std::to_string(chunk) + " " + std::to_string(tiles.size());
  for (const auto& t : tiles)
    line += " " + std::to_string(t.level) + "," + std::to_string(t.index) + "," +
            std::to_string(t.offset) + "," + std::to_string(t.size);
  line += " end\n";
  std::lock_guard<std::mutex> lock(mutex_);
  AppendAll(journal_fd_, line, journal_path_);
  for (const auto& t : tiles) Record(0, t);
  done_.insert(chunk);
}

bool TileJournal::IsDone(long long chunk) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return done_.count(chunk) > 0;
}

long long TileJournal::chunks_done() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<long long>(done_.size());
}

std::vector<uint8_t> TileJournal::Read(int level, long long index) const {
  Where e;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const size_t k = static_cast<size_t>(level + 1);
    if (k < levels_.size() && static_cast<size_t>(index) < levels_[k].size())
      e = levels_[k][static_cast<size_t>(index)];
  }
  if (e.size == 0)
    Fail(dir_, "tile " + std::to_string(index) + " of level " + std::to_string(level) + " was never written");
  const Part& part = parts_[static_cast<size_t>(e.part)];
  std::vector<uint8_t> buf(e.size);
  size_t done = 0;
  while (done < buf.size()) {
    const ssize_t n = ::pread(part.data_fd, buf.data() + done, buf.size() - done, static_cast<off_t>(e.offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) Fail(part.data_path, "cannot read back tile " + std::to_string(index) + " of level " + std::to_string(level));
    done += static_cast<size_t>(n);
  }
  return buf;
}

void TileJournal::WriteTiff(const std::string& path, const PixelLayout& layout,
                            const TiffWriteOptions& options,
                            const std::vector<long long>& tiles_per_level,
                            const std::vector<long long>& level_widths,
                            const std::vector<long long>& level_heights,
                            const std::vector<uint8_t>& jpeg_tables) const {
  const std::string tmp = TemporarySibling(path);
  // Each tile's bytes are freed once copied (a hole punched in the data file), so the disk holds
  // about one copy of the mosaic, not two; the journal says so first, for a run that dies here.
  if (free_while_writing_) {
    std::lock_guard<std::mutex> lock(mutex_);
    AppendAll(journal_fd_, "assembling\n", journal_path_);
  }
  try {
    auto file = TiffFile::Open(tmp, "w8");  // BigTIFF always
    TIFF* tif = file->get();
    for (size_t k = 0; k < tiles_per_level.size(); ++k) {
      if (k > 0 && !TIFFWriteDirectory(tif)) Fail(path, "cannot write directory: " + file->TakeError());
      LevelTags tags;
      tags.width = static_cast<uint32_t>(level_widths[k]);
      tags.height = static_cast<uint32_t>(level_heights[k]);
      tags.reduced = k > 0;
      SetLevelTags(tif, layout, options, tags, /*for_encoding=*/false);
      SetJpegTables(tif, jpeg_tables);
      for (long long i = 0; i < tiles_per_level[k]; ++i) {
        std::vector<uint8_t> bytes = Read(static_cast<int>(k), i);
        if (TIFFWriteRawTile(tif, static_cast<uint32_t>(i), bytes.data(), static_cast<tmsize_t>(bytes.size())) < 0)
          Fail(path, "cannot write tile " + std::to_string(i) + " of level " + std::to_string(k) + ": " + file->TakeError());
        if (free_while_writing_) Free(static_cast<int>(k), i);
      }
    }
    file->Close();
    RenameFile(tmp, path);
  } catch (...) {
    ::unlink(tmp.c_str());
    throw;
  }
}

void TileJournal::Free(int level, long long index) const {
  const Where& e = levels_[static_cast<size_t>(level + 1)][static_cast<size_t>(index)];
  if (e.part != 0) return;  // another writer's file: not ours to change
  // Only whole blocks are released; filesystems without holes keep the bytes (no error).
  ::fallocate(data_fd_, FALLOC_FL_PUNCH_HOLE | FALLOC_FL_KEEP_SIZE, static_cast<off_t>(e.offset), static_cast<off_t>(e.size));
}

std::set<long long> TileJournal::DoneChunks(const std::string& dir, const std::string& fingerprint) {
  TileJournal reader;  // a part of its own that never exists: Load reads all the others
  reader.dir_ = dir;
  reader.data_path_ = PartFile(dir, "tiles", "~reader", ".bin");
  reader.journal_path_ = PartFile(dir, "journal", "~reader", ".txt");
  std::error_code ec;
  if (fs::is_directory(dir, ec)) reader.Load(fingerprint);
  return reader.done_;
}

void TileJournal::Remove() {
  for (auto& p : parts_)
    if (p.data_fd >= 0 && p.data_fd != data_fd_) ::close(p.data_fd);
  parts_.clear();
  if (data_fd_ >= 0) ::close(data_fd_);
  if (journal_fd_ >= 0) ::close(journal_fd_);
  data_fd_ = journal_fd_ = -1;
  std::error_code ec;
  fs::remove_all(dir_, ec);
}

}  // namespace rolamos

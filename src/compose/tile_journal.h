// Resumable storage for a pyramid that is written tile by tile, in any order and from several
// threads: compressed tiles go to an append-only data file, and a journal records which chunks
// (groups of tiles) are complete. A run that dies (Ctrl-C, kill, full disk) loses only its
// unfinished chunks; the next run with the same inputs reads the journal and does the rest.
// WriteTiff() then lays the tiles out as the store's pyramidal BigTIFF.
//
// Several writers (shards of one compose, on other machines over a shared file system) each
// append to their own pair of files ("part"), never to another's: a journal reads every part's
// committed chunks, so any writer sees what all have done. Only plain appends, pwrite and pread
// are used (no mmap, no locks), which NFS and Lustre honour; freeing copied tiles by punching
// holes is an option, off for shared work.
#pragma once

#include <cstdint>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "rolamos/image_format.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct JournalTile {
  int level = 0;        // pyramid level; -1 for a chunk's raw root pixels
  long long index = 0;  // tile index in that level (row-major), or the chunk id for roots
  uint64_t offset = 0;
  uint32_t size = 0;
};

class TileJournal {
 public:
  // Opens or creates `dir`. A journal there that was written for another `fingerprint` (other
  // inputs or options), or any journal when `restart`, is discarded and discarded() says why.
  // `part` names this writer's files ("" for a single writer, e.g. "shard-2-of-8"); the parts
  // of other writers in `dir` are read (when written for the same fingerprint), never written.
  TileJournal(const std::string& dir, const std::string& fingerprint, bool restart,
              const std::string& part = "");
  ~TileJournal();
  TileJournal(const TileJournal&) = delete;
  TileJournal& operator=(const TileJournal&) = delete;

  // Appends bytes to the data file (thread-safe). They count only once Commit() names them.
  JournalTile Put(int level, long long index, const void* data, size_t size);
  // Records `chunk` complete with its tiles, in one append (thread-safe).
  void Commit(long long chunk, const std::vector<JournalTile>& tiles);
  bool IsDone(long long chunk) const;
  long long chunks_done() const;
  const std::string& discarded() const { return discarded_; }
  // Other writers' parts left aside because they were written for another fingerprint.
  const std::vector<std::string>& stale_parts() const { return stale_parts_; }
  // WriteTiff frees each tile of this writer's own part as it is copied (holes punched), so the
  // disk holds one copy of the mosaic; a writer that dies then cannot resume. On by default.
  void set_free_while_writing(bool on) { free_while_writing_ = on; }

  // The committed tile (level, index); throws Error when it was never committed.
  std::vector<uint8_t> Read(int level, long long index) const;
  // Writes the pyramid: `tiles_per_level[k]` tiles of level k, all of which must be committed.
  // The data file's copies are freed as they are written: afterwards the journal cannot be
  // resumed (a run that dies while this runs starts over).
  void WriteTiff(const std::string& path, const PixelLayout& layout,
                 const TiffWriteOptions& options, const std::vector<long long>& tiles_per_level,
                 const std::vector<long long>& level_widths,
                 const std::vector<long long>& level_heights,
                 const std::vector<uint8_t>& jpeg_tables) const;
  // The chunks every part in `dir` has committed for `fingerprint`, read without writing anything.
  static std::set<long long> DoneChunks(const std::string& dir, const std::string& fingerprint);

  // Deletes the directory (after the TIFF is in place).
  void Remove();

 private:
  TileJournal() = default;
  struct Where {
    int part = 0;  // index in parts_ (0: this writer's own)
    uint64_t offset = 0;
    uint32_t size = 0;
  };
  struct Part {
    std::string data_path, journal_path;
    int data_fd = -1;
  };
  void Load(const std::string& fingerprint);
  // Reads one part's journal; false when it was written for another fingerprint or was being
  // assembled (its tiles may be freed).
  bool LoadPart(int part, const std::string& fingerprint, std::string* why);
  void Record(int part, const JournalTile& t);
  void Free(int level, long long index) const;

  std::string dir_, data_path_, journal_path_;
  int data_fd_ = -1, journal_fd_ = -1;
  std::vector<Part> parts_;
  mutable std::mutex mutex_;
  uint64_t data_end_ = 0;
  std::set<long long> done_;
  std::vector<std::vector<Where>> levels_;  // [level+1][index]
  std::string discarded_;
  std::vector<std::string> stale_parts_;
  bool free_while_writing_ = true;
};

// A stable 64-bit hash (FNV-1a) as hex, for journal fingerprints.
std::string FingerprintHex(const std::string& text);

}  // namespace rolamos

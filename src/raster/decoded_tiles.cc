#include "raster/decoded_tiles.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <sstream>

namespace rolamos {

FileStamp FileStamp::Of(int fd) {
  struct stat st {};
  FileStamp f;
  if (::fstat(fd, &st) != 0) return f;
  f.inode = st.st_ino;
  f.size = static_cast<unsigned long long>(st.st_size);
  f.mtime_ns = static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
  return f;
}

FileStamp FileStamp::Of(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return {};
  const FileStamp f = Of(fd);
  ::close(fd);
  return f;
}

uint64_t DecodedTiles::FileId(const std::string& path, const FileStamp& stamp) {
  const std::string key = path + "|" + std::to_string(stamp.size) + "|" + std::to_string(stamp.mtime_ns) + "|" +
                          std::to_string(stamp.inode);
  std::lock_guard<std::mutex> lock(mutex_);
  auto [it, added] = file_ids_.emplace(key, next_id_);
  if (added) file_paths_[next_id_++] = path;
  return it->second;
}

std::shared_ptr<const cv::Mat> DecodedTiles::Find(uint64_t file, int level, int tx, int ty) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = index_.find(Key{file, level, tx, ty});
  if (it == index_.end()) {
    ++misses_;
    return nullptr;
  }
  ++hits_;
  order_.splice(order_.begin(), order_, it->second);
  return it->second->tile;
}

void DecodedTiles::Add(uint64_t file, int level, int tx, int ty, std::shared_ptr<const cv::Mat> tile) {
  const size_t bytes = tile->total() * tile->elemSize();
  std::lock_guard<std::mutex> lock(mutex_);
  const Key key{file, level, tx, ty};
  if (index_.count(key)) return;  // decoded by another thread meanwhile
  order_.push_front(Entry{key, std::move(tile), bytes});
  index_[key] = order_.begin();
  bytes_ += bytes;
  EvictLocked();
}

void DecodedTiles::EvictLocked() {
  // The newest tile stays even when it alone passes the limit: the read in progress needs it.
  while (bytes_ > max_bytes_ && order_.size() > 1) {
    const Entry& e = order_.back();
    bytes_ -= e.bytes;
    index_.erase(e.key);
    order_.pop_back();
    ++evicted_;
  }
}

void DecodedTiles::Forget(const std::string& path) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto it = order_.begin(); it != order_.end();) {
    auto p = file_paths_.find(it->key.file);
    if (p != file_paths_.end() && p->second == path) {
      bytes_ -= it->bytes;
      index_.erase(it->key);
      it = order_.erase(it);
    } else {
      ++it;
    }
  }
  // The ids too: a server that replaces its live preview several times a second for hours must
  // not keep a name per file it ever read.
  for (auto it = file_ids_.begin(); it != file_ids_.end();) {
    if (it->first == path || it->first.rfind(path + "|", 0) == 0) it = file_ids_.erase(it);
    else ++it;
  }
  for (auto it = file_paths_.begin(); it != file_paths_.end();) {
    if (it->second == path) it = file_paths_.erase(it);
    else ++it;
  }
}

size_t DecodedTiles::files() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return file_paths_.size();
}

size_t DecodedTiles::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return bytes_;
}

std::string DecodedTiles::Stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::ostringstream s;
  s << "decoded tiles (libtiff): " << order_.size() << " held, " << (bytes_ >> 20) << " of " << (max_bytes_ >> 20)
    << " MB, " << hits_ << " hits, " << misses_ << " misses, " << evicted_ << " evicted\n";
  return s.str();
}

}  // namespace rolamos

#include "store/writer_lock.h"

#include <cerrno>
#include <cstring>
#include <string>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include "rolamos/error.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

std::string StoreWriterLock::PathIn(const std::string& store_dir) { return store_dir + "/.writer.lock"; }

StoreWriterLock::StoreWriterLock(const Store& store, const std::string& who) : store_(std::make_unique<Store>(store)) {
  const std::string& store_dir = store.dir();
  const std::string path = PathIn(store_dir);
  fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) Fail(path, std::string("cannot be opened to lock the store for writing: ") + std::strerror(errno));
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    char holder[256] = {0};
    const ssize_t n = ::pread(fd_, holder, sizeof holder - 1, 0);
    ::close(fd_);
    fd_ = -1;
    if (error == EWOULDBLOCK) {
      std::string by = n > 0 ? std::string(holder, static_cast<size_t>(n)) : "another process";
      while (!by.empty() && (by.back() == '\n' || by.back() == ' ')) by.pop_back();
      Fail(store_dir, "is being written by " + by + "; try again when it has ended");
    }
    Fail(path, std::string("cannot be locked: ") + std::strerror(error));
  }
  {
    std::lock_guard<std::mutex> lock(store_->state_->mutex);
    ++store_->state_->writer_locks;
  }
  const std::string note = who + " (pid " + std::to_string(::getpid()) + ")\n";
  // Who holds it, for the message of whoever finds it held (a note only: the lock is the flock).
  if (::ftruncate(fd_, 0) == 0) {
    [[maybe_unused]] const ssize_t written = ::pwrite(fd_, note.data(), note.size(), 0);
  }
}

StoreWriterLock::~StoreWriterLock() {
  if (fd_ < 0) return;
  {
    std::lock_guard<std::mutex> lock(store_->state_->mutex);
    --store_->state_->writer_locks;
  }
  ::close(fd_);  // releases the lock
}

bool StoreWriterLock::HeldThrough(const Store& store) {
  std::lock_guard<std::mutex> lock(store.state_->mutex);
  return store.state_->writer_locks > 0;
}

std::unique_ptr<StoreWriterLock> LockStoreForChange(Store& store, const std::string& who) {
  if (StoreWriterLock::HeldThrough(store)) return nullptr;
  auto lock = std::make_unique<StoreWriterLock>(store, who);
  store.Reload();
  return lock;
}

}  // namespace rolamos

// One engine writes a store's patches at a time. Two would number their patches from what the
// store held when each opened it and overwrite each other's patches and sidecars: the frames of
// one run lost without a word. The lock is advisory (flock on STORE/.writer.lock, which names its
// holder), and the kernel lets go of it when the holder ends, however it ends (kill -9 included).
#pragma once

#include <string>

namespace rolamos {

class StoreWriterLock {
 public:
  // Takes the lock for `who` (e.g. "rolamos mosaic"); throws Error naming the store and the
  // process that holds it.
  StoreWriterLock(const std::string& store_dir, const std::string& who);
  ~StoreWriterLock();
  StoreWriterLock(const StoreWriterLock&) = delete;
  StoreWriterLock& operator=(const StoreWriterLock&) = delete;
  static std::string PathIn(const std::string& store_dir);

 private:
  int fd_ = -1;
};

}  // namespace rolamos

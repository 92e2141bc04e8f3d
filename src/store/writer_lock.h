// One engine writes a store's patches at a time. Two would number their patches from what the
// store held when each opened it and overwrite each other's patches and sidecars: the frames of
// one run lost without a word. The lock is advisory (flock on STORE/.writer.lock, which names its
// holder), and the kernel lets go of it when the holder ends, however it ends (kill -9 included).
#pragma once

#include <memory>
#include <string>

namespace rolamos {

class Store;

class StoreWriterLock {
 public:
  // Takes the lock for `who` (e.g. "rolamos mosaic"), held through `store` and its copies (their
  // changes do not take it again); throws Error naming the store and the process that holds it.
  // Another handle on the same store, in this process too, is refused as another process is.
  StoreWriterLock(const Store& store, const std::string& who);
  ~StoreWriterLock();
  StoreWriterLock(const StoreWriterLock&) = delete;
  StoreWriterLock& operator=(const StoreWriterLock&) = delete;
  static std::string PathIn(const std::string& store_dir);
  // Whether a StoreWriterLock holds the lock through `store` (or a copy of it) now.
  static bool HeldThrough(const Store& store);

 private:
  int fd_ = -1;
  std::unique_ptr<Store> store_;  // shares the handle's state, which counts the locks held through it
};

// For a step that reads the store, then changes it (relink, georeference, one manifest write):
// the lock, taken for `who` and `store` read again; null where it is held through `store` already
// (the compose command holds it across its steps; an engine commits through its own handle).
std::unique_ptr<StoreWriterLock> LockStoreForChange(Store& store, const std::string& who);

}  // namespace rolamos

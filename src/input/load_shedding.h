// When a live run sheds load (LiveOptions::shed_describe_overlap): from the backlog, the frames
// received and not yet mapped, after each frame mapped. On when the backlog reaches half its
// bound, off once it is down to a quarter: between the two the engine keeps what it does, so a
// backlog that hovers about one mark does not switch it every frame.
#pragma once

namespace rolamos {

class LoadShedding {
 public:
  // `bound`: LiveOptions::max_waiting.
  explicit LoadShedding(int bound);
  // The backlog now; returns whether to shed for the frames that follow.
  bool Update(int backlog);
  bool on() const { return on_; }

 private:
  int on_at_, off_at_;
  bool on_ = false;
};

}  // namespace rolamos

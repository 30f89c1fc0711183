//! Sequence numbers of one session: which frames were lost, repeated or arrived late. A link that drops
//! and repeats frames must still merge each frame exactly once, and report what it never got.

/// What [`SeqTracker::accept`] decided about a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SeqVerdict {
    /// The newest frame so far (frames skipped over are counted lost).
    New,
    /// An older frame not received before (it had been counted lost; no longer).
    Late,
    /// Received before: drop it.
    Duplicate,
    /// Older than the 64-frame window: drop it.
    TooOld,
}

/// Sequence numbers of one session: counts lost, duplicate and late frames (a 64-frame window).
/// Serializable so that a receiver can persist it with the frames it marks merged (the base station's
/// database).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SeqTracker {
    started: bool,
    highest: u32,
    window: u64,
    /// Frames accepted (new or late).
    pub received: u32,
    /// Frames never received: sequence numbers skipped and not filled in later.
    pub lost: u32,
    /// Frames received twice (dropped).
    pub duplicates: u32,
    /// Frames that arrived after a newer one (accepted).
    pub late: u32,
    /// Frames older than the window (dropped).
    pub too_old: u32,
}

impl SeqTracker {
    /// Record a frame's sequence number; say whether to accept it. The session starts at sequence 0, so
    /// a first frame numbered n means n frames were lost before it.
    pub fn accept(&mut self, seq: u32) -> SeqVerdict {
        if !self.started {
            self.started = true;
            self.highest = seq;
            self.window = 1;
            self.lost = self.lost.saturating_add(seq);
            self.received = self.received.saturating_add(1);
            return SeqVerdict::New;
        }
        let ahead = seq.wrapping_sub(self.highest);
        if ahead != 0 && ahead < 1 << 31 {
            self.lost = self.lost.saturating_add(ahead - 1);
            self.window = if ahead >= 64 { 0 } else { self.window << ahead };
            self.window |= 1;
            self.highest = seq;
            self.received = self.received.saturating_add(1);
            return SeqVerdict::New;
        }
        let back = self.highest.wrapping_sub(seq);
        if back >= 64 {
            self.too_old = self.too_old.saturating_add(1);
            return SeqVerdict::TooOld;
        }
        if self.window >> back & 1 == 1 {
            self.duplicates = self.duplicates.saturating_add(1);
            return SeqVerdict::Duplicate;
        }
        self.window |= 1 << back;
        self.lost = self.lost.saturating_sub(1);
        self.late = self.late.saturating_add(1);
        self.received = self.received.saturating_add(1);
        SeqVerdict::Late
    }

    /// The sequence state of two receivers of one session together (merging two maps' databases): a frame
    /// either received counts as received, so the union refuses every copy either would have. The window
    /// is exact; `received` is the larger of the two plus the frames only the other's window shows, and
    /// `lost` what the union's numbers leave unfilled (frames before both windows are counted as the
    /// higher one counted them).
    pub fn union(&self, other: &Self) -> Self {
        if !other.started {
            return *self;
        }
        if !self.started {
            return *other;
        }
        let (hi, lo) = if other.highest.wrapping_sub(self.highest) < 1 << 31 {
            (other, self)
        } else {
            (self, other)
        };
        let shift = hi.highest.wrapping_sub(lo.highest);
        let lo_window = if shift >= 64 { 0 } else { lo.window << shift };
        let window = hi.window | lo_window;
        let gained = (window & !hi.window).count_ones();
        let received = hi.received.saturating_add(gained);
        Self {
            started: true,
            highest: hi.highest,
            window,
            received,
            lost: hi.lost.saturating_sub(gained),
            duplicates: hi.duplicates.max(lo.duplicates),
            late: hi.late.max(lo.late),
            too_old: hi.too_old.max(lo.too_old),
        }
    }

    /// Highest sequence number seen (if any).
    pub fn highest(&self) -> Option<u32> {
        self.started.then_some(self.highest)
    }

    /// The 64 sequence numbers ending at [`Self::highest`]: bit i set means `highest − i` was received
    /// (what an acknowledgement carries, [`crate::frame::Ack`]).
    pub fn window(&self) -> u64 {
        self.window
    }
}

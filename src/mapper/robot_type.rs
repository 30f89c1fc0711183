//! The map's type written once: a firmware names its feature dimension, capacity, queue and frame sizes,
//! and [`mapper_type!`](crate::mapper_type) fills in the rest — the packed code length `packed_len(D)`
//! (stable Rust cannot compute it from a generic `D` inside a type alias) and the defaults.

/// The [`Mapper`](crate::Mapper) type of a robot, from what its author chooses:
/// `mapper_type!(D, CAP, QB, N)` is `Mapper<D, CAP, { packed_len(D) }, QB, N>` — feature dimension,
/// voxels held, bytes of the queue of evicted voxels, largest frame on the wire. A fifth argument sets the
/// hot tier's size `H`, a sixth the map's clock (e.g. `latentbki::forget::Fading`).
///
/// ```
/// use latentbki::{mapper_type, packed_len, Mapper};
/// type Robot = mapper_type!(64, 1024, 4096, 512);
/// type Spelled = Mapper<64, 1024, { packed_len(64) }, 4096, 512>;
/// assert_eq!(Robot::RAM_BYTES, Spelled::RAM_BYTES);
///
/// type Forgetting = mapper_type!(64, 1024, 4096, 512, 8, latentbki::forget::Fading);
/// assert!(Forgetting::RAM_BYTES > <mapper_type!(64, 1024, 4096, 512, 8)>::RAM_BYTES);
/// ```
#[macro_export]
macro_rules! mapper_type {
    ($d:expr, $cap:expr, $qb:expr, $n:expr $(,)?) => {
        $crate::Mapper<{ $d }, { $cap }, { $crate::packed_len($d) }, { $qb }, { $n }>
    };
    ($d:expr, $cap:expr, $qb:expr, $n:expr, $h:expr $(,)?) => {
        $crate::Mapper<{ $d }, { $cap }, { $crate::packed_len($d) }, { $qb }, { $n }, { $h }>
    };
    ($d:expr, $cap:expr, $qb:expr, $n:expr, $h:expr, $clock:ty $(,)?) => {
        $crate::Mapper<{ $d }, { $cap }, { $crate::packed_len($d) }, { $qb }, { $n }, { $h }, $clock>
    };
}

//! Information gain over the house's rooms (`--rooms`): the next view is the best view, by score / (path +
//! offset), in the first room of the best tour of the rooms.
//!
//! Why: a single view's utility is a rate, and once the first rooms are seen it can keep choosing short hops
//! to leftovers while a room with much unseen surface waits behind a long drive. Here each room is worth
//! what all its views could still teach together (every voxel a view from inside the room reaches, at the
//! largest kernel weight any of them would give it: the room's summed score), and the rooms are ordered
//! as a tour that maximises Σ worth / (distance driven to reach it + offset), so that a room is visited for
//! what it holds and a room already exhausted is left. Measured in `docs/numbers.md` (exploration).

use super::tour::Candidate;
use super::world::Viewpoint;
use super::Robot;
use latentbki::info_gain::voxel_gain;

impl Robot<'_> {
    /// The room each candidate place lies in (None: a doorway or outside every room's floor).
    fn room_of(&self, cell: usize) -> Option<usize> {
        let c = self.world.centre(cell);
        self.world
            .scene
            .rooms
            .iter()
            .position(|r| (0..2).all(|a| c[a] >= r.min[a] && c[a] <= r.max[a]))
    }

    /// The best view in the first room of the best room tour, among `options` (all within the budget).
    pub(super) fn choose_room_tour(&self, options: &[Candidate]) -> Option<Viewpoint> {
        let rooms = self.world.scene.rooms.len();
        let room: Vec<Option<usize>> = options.iter().map(|o| self.room_of(o.0.cell)).collect();
        // Each room's worth: Σ gain(λ, largest weight any of its views would give) over what they reach.
        let mut worth = vec![0.0f32; rooms];
        let mut largest = vec![0.0f32; self.seen.len()];
        for (r, w) in worth.iter_mut().enumerate() {
            largest.iter_mut().for_each(|x| *x = 0.0);
            for (o, _) in options.iter().zip(&room).filter(|(_, q)| **q == Some(r)) {
                for &(s, w) in &o.1.slot_weights {
                    let l = &mut largest[s as usize];
                    *l = l.max(w);
                }
            }
            *w = largest
                .iter()
                .enumerate()
                .filter(|(_, &w)| w > 0.0)
                .map(|(s, &w)| voxel_gain(self.prior_lambda + self.seen[s], w))
                .sum();
        }
        // Driving distance to each room (its nearest candidate) and between rooms (centre to centre).
        let reach: Vec<f32> = (0..rooms)
            .map(|r| {
                options
                    .iter()
                    .zip(&room)
                    .filter(|(_, q)| **q == Some(r))
                    .map(|(o, _)| o.2)
                    .fold(f32::INFINITY, f32::min)
            })
            .collect();
        let centres: Vec<Option<usize>> = (0..rooms)
            .map(|r| self.world.nearest_free(self.world.scene.room_centre(r)))
            .collect();
        let between: Vec<Vec<f32>> = centres
            .iter()
            .map(|&c| match c {
                Some(c) => {
                    let d = self.world.distances(c).0;
                    centres
                        .iter()
                        .map(|&o| o.map_or(f32::INFINITY, |o| d[o]))
                        .collect()
                }
                None => vec![f32::INFINITY; rooms],
            })
            .collect();
        let open: Vec<usize> = (0..rooms).filter(|&r| reach[r].is_finite()).collect();
        let mut best: Option<(f32, usize)> = None;
        permutations(&open, &mut Vec::new(), &mut |tour| {
            let (mut driven, mut value) = (reach[tour[0]], 0.0);
            for (k, &r) in tour.iter().enumerate() {
                if k > 0 {
                    driven += between[tour[k - 1]][r];
                }
                value += worth[r] / (driven + self.utility_offset);
            }
            if best.is_none_or(|(v, _)| value > v) {
                best = Some((value, tour[0]));
            }
        });
        let first = best?.1;
        options
            .iter()
            .zip(&room)
            .filter(|(_, q)| **q == Some(first))
            .map(|(o, _)| o)
            .max_by(|a, b| {
                self.utility(self.score(a.1), a.2)
                    .total_cmp(&self.utility(self.score(b.1), b.2))
            })
            .map(|o| o.0)
    }
}

/// Call `f` with every ordering of `items` (at most a house's four rooms: 24 orderings).
fn permutations(items: &[usize], prefix: &mut Vec<usize>, f: &mut dyn FnMut(&[usize])) {
    if items.is_empty() {
        if !prefix.is_empty() {
            f(prefix);
        }
        return;
    }
    for i in 0..items.len() {
        let mut rest = items.to_vec();
        let x = rest.remove(i);
        prefix.push(x);
        permutations(&rest, prefix, f);
        prefix.pop();
    }
}

//! The order a diagram stops in: producers before their consumers, each consumer stopped only once it has
//! read what its producers wrote before they stopped (within a bound). Without it a stop request reaches
//! every thread at once and a sample between a producer and a slower consumer (a frame between a link's
//! receiver and a recorder) is neither recorded nor counted as lost.

use std::collections::BTreeMap;

use kairos_diagram::ReaderPolicy;

/// One link as the engine attached it: who reads whose buffer, under which name and policy.
pub(crate) struct AttachedLink {
    pub producer: String,
    pub consumer: String,
    /// The producer's buffer, by its place among the engine's buffers.
    pub buffer: usize,
    pub link: String,
    pub policy: ReaderPolicy,
    pub subsampling: u32,
}

/// A link to wait on before its consumer stops.
pub(crate) struct Drain {
    /// The slot of the consumer.
    pub consumer: usize,
    pub buffer: usize,
    pub link: String,
    /// Fewer samples than this still queued is drained: a subsampling reader never reads the ones it
    /// passes over until a kept one comes, and none will.
    pub below: u64,
}

/// Components (by their slot) and groups stopped together, after every earlier layer has been joined.
#[derive(Default)]
pub(crate) struct StopLayer {
    pub slots: Vec<usize>,
    pub groups: Vec<usize>,
    /// Empty for the last layer of components in a cycle: they feed each other and are stopped at once.
    pub drains: Vec<Drain>,
}

/// What stops as one: a component, or an execution group whose thread runs several.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Unit {
    Slot(usize),
    Group(usize),
}

/// The layers, in the order to stop them: each unit one past the deepest of its producers; units in a
/// cycle (and what they feed) in a last layer of their own, which waits for nothing.
///
/// `group_of` gives a slot's execution group, when it has one.
pub(crate) fn stop_layers(
    slot_ids: &[&str],
    group_of: &dyn Fn(usize) -> Option<usize>,
    links: &[AttachedLink],
) -> Vec<StopLayer> {
    let slot_index: BTreeMap<&str, usize> = slot_ids.iter().enumerate().map(|(i, id)| (*id, i)).collect();
    let unit_of = |slot: usize| group_of(slot).map_or(Unit::Slot(slot), Unit::Group);
    let mut units: BTreeMap<Unit, Vec<usize>> = BTreeMap::new();
    for slot in 0..slot_ids.len() {
        units.entry(unit_of(slot)).or_default().push(slot);
    }
    let mut feeds: BTreeMap<Unit, Vec<Unit>> = BTreeMap::new();
    let mut waiting_on: BTreeMap<Unit, usize> = units.keys().map(|unit| (*unit, 0)).collect();
    let mut drains: BTreeMap<Unit, Vec<Drain>> = BTreeMap::new();
    for link in links {
        let (Some(&from), Some(&to)) = (
            slot_index.get(link.producer.as_str()),
            slot_index.get(link.consumer.as_str()),
        ) else {
            continue;
        };
        let consumer = to;
        let (from, to) = (unit_of(from), unit_of(to));
        if from == to {
            continue;
        }
        feeds.entry(from).or_default().push(to);
        *waiting_on.entry(to).or_default() += 1;
        // Sampling reads the newest again and again, WaitForNext only what comes after it asks: neither
        // has anything left to read once its producer stopped.
        if matches!(
            link.policy,
            ReaderPolicy::Fifo | ReaderPolicy::NeverSkipping | ReaderPolicy::LastOrNext
        ) {
            drains.entry(to).or_default().push(Drain {
                consumer,
                buffer: link.buffer,
                link: link.link.clone(),
                below: u64::from(link.subsampling.max(1)),
            });
        }
    }
    // Kahn's order, each unit one layer past its deepest producer.
    let mut depth: BTreeMap<Unit, usize> = BTreeMap::new();
    let mut ready: Vec<Unit> = waiting_on
        .iter()
        .filter(|(_, producers)| **producers == 0)
        .map(|(unit, _)| *unit)
        .collect();
    for unit in &ready {
        depth.insert(*unit, 0);
    }
    while let Some(unit) = ready.pop() {
        let here = depth[&unit];
        for consumer in feeds.get(&unit).into_iter().flatten() {
            let deepest = depth.entry(*consumer).or_insert(0);
            *deepest = (*deepest).max(here + 1);
            if let Some(left) = waiting_on.get_mut(consumer) {
                *left -= 1;
                if *left == 0 {
                    ready.push(*consumer);
                }
            }
        }
    }
    let ordered = depth.values().copied().max().map_or(0, |deepest| deepest + 1);
    let mut layers: Vec<StopLayer> = (0..ordered).map(|_| StopLayer::default()).collect();
    let mut in_cycles = StopLayer::default();
    for (unit, slots) in units {
        let finished = waiting_on.get(&unit).is_none_or(|left| *left == 0);
        let layer = match depth.get(&unit) {
            Some(&layer) if finished => {
                let layer = &mut layers[layer];
                layer.drains.extend(drains.remove(&unit).unwrap_or_default());
                layer
            }
            _ => &mut in_cycles,
        };
        layer.slots.extend(slots);
        if let Unit::Group(group) = unit {
            layer.groups.push(group);
        }
    }
    layers.push(in_cycles);
    // A unit reached from a cycle got a depth but stops with the cycle: its layer may be left empty.
    layers.retain(|layer| !layer.slots.is_empty());
    layers
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(producer: &str, consumer: &str, policy: ReaderPolicy) -> AttachedLink {
        AttachedLink {
            producer: producer.to_owned(),
            consumer: consumer.to_owned(),
            buffer: 0,
            link: format!("{producer}.out -> {consumer}.in"),
            policy,
            subsampling: 1,
        }
    }

    fn slots_by_layer(layers: &[StopLayer]) -> Vec<Vec<usize>> {
        layers.iter().map(|layer| layer.slots.clone()).collect()
    }

    #[test]
    fn producers_stop_before_their_consumers() {
        // 0 -> 1 -> 2, and 0 -> 2 directly: 2 waits for 1.
        let links = [
            link("a", "b", ReaderPolicy::Fifo),
            link("b", "c", ReaderPolicy::NeverSkipping),
            link("a", "c", ReaderPolicy::Sampling),
        ];
        let layers = stop_layers(&["a", "b", "c"], &|_| None, &links);
        assert_eq!(slots_by_layer(&layers), [vec![0], vec![1], vec![2]]);
        assert_eq!(
            layers[2].drains.len(),
            1,
            "a Sampling reader has nothing to drain"
        );
        assert_eq!(layers[2].drains[0].link, "b.out -> c.in");
    }

    #[test]
    fn a_cycle_stops_last_and_at_once_with_what_it_feeds() {
        let links = [
            link("src", "x", ReaderPolicy::Fifo),
            link("x", "y", ReaderPolicy::Fifo),
            link("y", "x", ReaderPolicy::Fifo),
            link("y", "sink", ReaderPolicy::Fifo),
        ];
        let layers = stop_layers(&["src", "x", "y", "sink"], &|_| None, &links);
        assert_eq!(slots_by_layer(&layers), [vec![0], vec![1, 2, 3]]);
        assert!(layers[1].drains.is_empty());
    }

    #[test]
    fn a_group_stops_as_one_and_its_own_links_are_not_waited_on() {
        // Slots 1 and 2 share group 0; 0 feeds 1, 1 feeds 2, 2 feeds 3.
        let links = [
            link("a", "b", ReaderPolicy::Fifo),
            link("b", "c", ReaderPolicy::Fifo),
            link("c", "d", ReaderPolicy::Fifo),
        ];
        let group_of = |slot: usize| (slot == 1 || slot == 2).then_some(0);
        let layers = stop_layers(&["a", "b", "c", "d"], &group_of, &links);
        assert_eq!(slots_by_layer(&layers), [vec![0], vec![1, 2], vec![3]]);
        assert_eq!(layers[1].groups, [0]);
        assert_eq!(layers[1].drains.len(), 1);
        assert_eq!(layers[1].drains[0].link, "a.out -> b.in");
    }
}

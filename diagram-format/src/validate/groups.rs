//! Execution groups: what can share one thread, and what cannot.
//!
//! A group runs its members one after the other in one thread, in the order of the links between them.
//! So its members must be on one machine, must not wait for long inside a call (a group has at most one
//! such member, its driver, whose waiting paces the rest), and must not feed each other in a loop (the
//! order would have no first member, and a sample going round would keep the thread busy for ever).

use std::collections::BTreeMap;

use super::{Validator, is_valid_path_id, join_with_and, strongly_connected_components};
use crate::diagnostic::{Diagnostic, DiagnosticCode, Location};
use crate::library::ReaderPolicy;
use crate::model::SEQUENTIAL_GROUP;

impl Validator<'_> {
    pub(super) fn check_groups(&mut self) {
        self.check_group_names();
        let mut members: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
        for (index, component) in self.diagram.components.iter().enumerate() {
            if let Some(group) = self.diagram.group_of(component) {
                members.entry(group).or_default().push(index);
            }
        }
        for (group, indices) in &members {
            self.check_one_host(group, indices);
            self.check_one_driver(group, indices);
        }
        self.check_group_cycles();
        self.check_never_skipping_inside();
    }

    /// Where component `index` names its group; the `sequential` switch for a sequential diagram.
    fn group_location(&self, index: usize) -> Option<Location> {
        if self.diagram.sequential {
            return self.source_map.and_then(|m| m.sequential);
        }
        self.component_at(index).and_then(|l| l.group)
    }

    fn check_group_names(&mut self) {
        for (name, settings) in &self.diagram.groups {
            let at = self.source_map.and_then(|m| m.groups.get(name)).copied();
            if !is_valid_path_id(name) {
                self.found.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidId,
                        format!("'{name}' cannot name an execution group: use letters, digits, _ and -"),
                    )
                    .at(at.map(|l| l.name)),
                );
            }
            if let Some(priority) = settings.priority.filter(|p| !(1..=99).contains(p)) {
                self.found.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidSetting,
                        format!("thread priority {priority} of group '{name}' is out of range 1..=99"),
                    )
                    .at(at.and_then(|l| l.priority))
                    .with_suggestion(Some("leave priority out to keep the normal scheduler".to_owned())),
                );
            }
            let named = if self.diagram.sequential {
                name == SEQUENTIAL_GROUP
            } else {
                self.diagram
                    .components
                    .iter()
                    .any(|c| c.group.as_ref() == Some(name))
            };
            if !named {
                let why = if self.diagram.sequential {
                    format!("the diagram is sequential: everything runs in group '{SEQUENTIAL_GROUP}'")
                } else {
                    "no component names it".to_owned()
                };
                self.found.push(
                    Diagnostic::warning(
                        DiagnosticCode::InvalidGroup,
                        format!("execution group '{name}' has no member: {why}"),
                    )
                    .at(at.map(|l| l.name)),
                );
            }
        }
        for (index, component) in self.diagram.components.iter().enumerate() {
            if let Some(group) = self.diagram.group_of(component)
                && !component.thread.is_default()
            {
                self.found.push(
                    Diagnostic::warning(
                        DiagnosticCode::InvalidGroup,
                        format!(
                            "the thread settings of '{}' are not used: it runs in group '{group}', whose thread \
                             has settings of its own",
                            component.id
                        ),
                    )
                    .at(self.component_at(index).and_then(|l| l.priority.or(l.group)))
                    .with_suggestion(Some(format!(
                        "set them for the group: groups: {{ \"{group}\": (priority: .., affinity: [..]) }}"
                    ))),
                );
            }
            let Some(group) = &component.group else { continue };
            let at = self.component_at(index).and_then(|l| l.group);
            if !is_valid_path_id(group) {
                self.found.push(
                    Diagnostic::error(
                        DiagnosticCode::InvalidId,
                        format!(
                            "'{group}' cannot name the execution group of '{}': use letters, digits, _ and -",
                            component.id
                        ),
                    )
                    .at(at),
                );
            } else if self.diagram.sequential {
                self.found.push(
                    Diagnostic::warning(
                        DiagnosticCode::InvalidGroup,
                        format!(
                            "'{}' names group '{group}', but the diagram is sequential: it runs in group \
                             '{SEQUENTIAL_GROUP}' with every other component",
                            component.id
                        ),
                    )
                    .at(at)
                    .with_suggestion(Some(
                        "remove `sequential: true` to use groups of your own".to_owned(),
                    )),
                );
            }
        }
    }

    /// A group is one thread: all its members on one machine.
    fn check_one_host(&mut self, group: &str, indices: &[usize]) {
        let components = &self.diagram.components;
        let Some(first) = indices.first().and_then(|&i| components.get(i)) else {
            return;
        };
        for &index in indices.iter().skip(1) {
            let Some(component) = components.get(index) else {
                continue;
            };
            if component.host == first.host {
                continue;
            }
            let place = |host: &Option<String>| {
                host.as_ref()
                    .map_or_else(|| "the deploying machine".to_owned(), |h| format!("host '{h}'"))
            };
            self.found.push(
                Diagnostic::error(
                    DiagnosticCode::InvalidGroup,
                    format!(
                        "group '{group}' runs in one thread, but '{}' is on {} and '{}' on {}",
                        first.id,
                        place(&first.host),
                        component.id,
                        place(&component.host)
                    ),
                )
                .at(self.group_location(index))
                .with_suggestion(Some(format!(
                    "give the members on {} a group of their own",
                    place(&component.host)
                ))),
            );
            return;
        }
    }

    /// At most one member that waits for long: it drives the group, the others run after each of its
    /// cycles.
    fn check_one_driver(&mut self, group: &str, indices: &[usize]) {
        let blocking: Vec<(usize, String)> = indices
            .iter()
            .filter_map(|&index| {
                let component = self.diagram.components.get(index)?;
                let reason = self.info_of(component)?.blocking_reason()?;
                Some((index, reason))
            })
            .collect();
        if let [(driver, reason)] = blocking.as_slice() {
            self.check_driver_inputs(group, *driver, reason);
        }
        let [(first, first_reason), (second, second_reason), ..] = blocking.as_slice() else {
            return;
        };
        let id = |index: usize| {
            self.diagram
                .components
                .get(index)
                .map(|c| c.id.clone())
                .unwrap_or_default()
        };
        let message = format!(
            "group '{group}' can hold one member that waits (its driver), but two do: '{}' ({first_reason}) \
             and '{}' ({second_reason})",
            id(*first),
            id(*second)
        );
        let suggestion = if self.diagram.sequential {
            format!(
                "remove `sequential: true` and put '{}' and what it feeds in a group of their own",
                id(*second)
            )
        } else {
            format!("run '{}' in a thread of its own: remove its `group`", id(*second))
        };
        self.found.push(
            Diagnostic::error(DiagnosticCode::InvalidGroup, message)
                .at(self.group_location(*second))
                .with_suggestion(Some(suggestion)),
        );
    }

    /// The driver runs first and waits inside its call: fed by its own group, it would wait for a member
    /// that runs only after it returns.
    fn check_driver_inputs(&mut self, group: &str, driver: usize, reason: &str) {
        let Some(component) = self.diagram.components.get(driver) else {
            return;
        };
        for (index, connection) in self.diagram.connections.iter().enumerate() {
            if connection.to.component != component.id {
                continue;
            }
            let Some(producer) = self
                .first_with_id
                .get(connection.from.component.as_str())
                .and_then(|&i| self.diagram.components.get(i))
            else {
                continue;
            };
            if self.diagram.group_of(producer) != Some(group) {
                continue;
            }
            self.found.push(
                Diagnostic::error(
                    DiagnosticCode::InvalidGroup,
                    format!(
                        "'{}' drives group '{group}' (it waits: {reason}), but '{}' of the same group feeds it: \
                         it would wait for a member that runs only after it",
                        component.id, producer.id
                    ),
                )
                .at(self.connection_at(index).map(|l| l.connection))
                .with_suggestion(Some(format!(
                    "run '{}' in a thread of its own, or '{}' and what feeds it in another group",
                    component.id, producer.id
                ))),
            );
            return;
        }
    }

    /// A NeverSkipping reader makes its writer wait for room; inside a group the reader runs only after
    /// the writer's call returns, so a call that writes more than the link holds cannot wait: the
    /// runtime fails the writer rather than hang the group.
    fn check_never_skipping_inside(&mut self) {
        for (index, connection) in self.diagram.connections.iter().enumerate() {
            let (Some(from), Some(to)) = (
                self.instance(&connection.from.component),
                self.instance(&connection.to.component),
            ) else {
                continue;
            };
            let Some(group) = self.diagram.group_of(from) else {
                continue;
            };
            if self.diagram.group_of(to) != Some(group) {
                continue;
            }
            let policy = connection.policy.or_else(|| {
                self.info_of(to)?
                    .input(&connection.to.port)
                    .map(|input| input.default_policy)
            });
            if policy != Some(ReaderPolicy::NeverSkipping) {
                continue;
            }
            self.found.push(
                Diagnostic::warning(
                    DiagnosticCode::InvalidGroup,
                    format!(
                        "'{}' reads '{}' NeverSkipping inside group '{group}': if one call of '{}' writes more \
                         samples than the link holds, it cannot wait for a reader that runs only after it returns, \
                         and '{}' fails",
                        connection.to.component,
                        connection.from,
                        connection.from.component,
                        connection.from.component
                    ),
                )
                .at(self.connection_at(index).map(|l| l.connection))
                .with_suggestion(Some(
                    "inside a group Fifo loses nothing when each call writes what the link holds; or give the \
                     link a buffer_size above what one call writes"
                        .to_owned(),
                )),
            );
        }
    }

    /// Members that feed each other in a loop have no order to run in.
    fn check_group_cycles(&mut self) {
        let components = &self.diagram.components;
        let group_of = |id: &str| -> Option<(usize, &str)> {
            let index = self.first_with_id.get(id).copied()?;
            let component = components.get(index)?;
            Some((index, self.diagram.group_of(component)?))
        };
        let mut edges: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        let mut edge_connections: Vec<(usize, usize, usize)> = Vec::new();
        for (index, connection) in self.diagram.connections.iter().enumerate() {
            let (Some((from, from_group)), Some((to, to_group))) = (
                group_of(&connection.from.component),
                group_of(&connection.to.component),
            ) else {
                continue;
            };
            // A member that holds its inputs (a simulator) is not ordered by them: a loop closes there.
            let holds = components
                .get(to)
                .and_then(|c| self.info_of(c))
                .is_some_and(|info| info.holds_inputs);
            if from_group != to_group || holds {
                continue;
            }
            edges.entry(from).or_default().push(to);
            edges.entry(to).or_default();
            edge_connections.push((from, to, index));
        }
        for members in strongly_connected_components(&edges) {
            let Some(&(from, _, connection)) = edge_connections
                .iter()
                .find(|(from, to, _)| members.contains(from) && members.contains(to))
            else {
                continue;
            };
            let group = components
                .get(from)
                .and_then(|c| self.diagram.group_of(c))
                .unwrap_or_default();
            let ids: Vec<String> = members
                .iter()
                .filter_map(|&i| components.get(i))
                .map(|c| format!("'{}'", c.id))
                .collect();
            let message = if ids.len() == 1 {
                let id = components.get(from).map(|c| c.id.as_str()).unwrap_or_default();
                format!(
                    "'{id}' feeds itself inside group '{group}': a group's members run in the order of their links, and a loop has no first"
                )
            } else {
                format!(
                    "{} feed each other in a loop inside group '{group}': a group's members run in the order \
                     of their links, and a loop has no first",
                    join_with_and(&ids)
                )
            };
            self.found.push(
                Diagnostic::error(DiagnosticCode::GroupCycle, message)
                    .at(self.connection_at(connection).map(|l| l.connection))
                    .with_suggestion(Some(if self.diagram.sequential {
                        "a sequential diagram cannot hold a loop: remove `sequential: true` and group the \
                         rest"
                            .to_owned()
                    } else {
                        "run one component of the loop in a thread of its own (remove its `group`)".to_owned()
                    })),
            );
        }
    }
}

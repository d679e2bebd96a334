//! The registry packs add their components to, the way a plugin builds an application.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::sync::Arc;

use kairos_diagram::{
    ComponentInfo, DescribeError, Diagnostic, Diagram, InstanceInfos, LibraryInfo, PackInfo, SourceMap, Value,
};

use crate::component::Component;

/// Makes a new instance of a component.
pub type Factory = Arc<dyn Fn() -> Box<dyn Component> + Send + Sync>;

/// Describes one instance of a component type whose ports depend on its properties (a player's
/// outputs are the channels of its recording), from the instance's resolved properties.
pub type Describe =
    Arc<dyn Fn(&BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> + Send + Sync>;

/// A component type: its descriptor and how to make one.
#[derive(Clone)]
pub struct RegisteredComponent {
    /// The descriptor: for a type with `describe`, what holds before its properties are known.
    pub info: ComponentInfo,
    /// The factory.
    pub factory: Factory,
    /// For types whose ports depend on their properties: the descriptor of one instance.
    pub describe: Option<Describe>,
}

impl fmt::Debug for RegisteredComponent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RegisteredComponent")
            .field("type_name", &self.info.type_name)
            .finish_non_exhaustive()
    }
}

/// A component type offered by two packs: the first one registered is kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DuplicateComponent {
    /// The type name.
    pub type_name: String,
    /// The pack whose component is kept.
    pub kept_from: String,
    /// The pack whose component was refused.
    pub refused_from: String,
}

/// A component type a pack may not register: its name is not under the pack's own (`faulty` may register
/// `faulty.probe`, never `core.gain`), so it could take another pack's place.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RefusedComponent {
    /// The type name the pack tried to register.
    pub type_name: String,
    /// The pack.
    pub pack: String,
    /// Where the pack came from (`built-in` or its library's path).
    pub origin: String,
    /// Why, and the fix.
    pub reason: String,
}

/// Every pack and component the runtime knows.
#[derive(Debug, Default)]
pub struct Registry {
    packs: BTreeMap<String, PackInfo>,
    components: BTreeMap<String, RegisteredComponent>,
    custom_types: BTreeSet<String>,
    duplicates: Vec<DuplicateComponent>,
    refused: Vec<RefusedComponent>,
    /// What was refused, kept whole: a pack library exports these too, so that the runtime loading it
    /// refuses them where it can say so, with the library's path.
    refused_registrations: Vec<RegisteredComponent>,
    /// The subgraphs packs ship: type name (`vision.lane_pipeline`) → diagram text.
    subgraphs: BTreeMap<String, String>,
}

impl Registry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts registering the pack `name` at `version` (semantic version), loaded from `origin`.
    pub fn pack(&mut self, name: &str, version: &str, origin: &str) -> PackRegistrar<'_> {
        self.packs.insert(
            name.to_owned(),
            PackInfo {
                name: name.to_owned(),
                version: version.to_owned(),
                origin: origin.to_owned(),
            },
        );
        PackRegistrar {
            registry: self,
            pack: name.to_owned(),
        }
    }

    /// The component type with this name.
    pub fn component(&self, type_name: &str) -> Option<&RegisteredComponent> {
        self.components.get(type_name)
    }

    /// Every component type, by name.
    pub fn components(&self) -> impl Iterator<Item = &RegisteredComponent> {
        self.components.values()
    }

    /// Every pack, by name.
    pub fn packs(&self) -> impl Iterator<Item = &PackInfo> {
        self.packs.values()
    }

    /// The subgraphs packs ship: type name → diagram text.
    pub fn subgraphs(&self) -> &BTreeMap<String, String> {
        &self.subgraphs
    }

    /// Component types offered twice, and which pack won.
    pub fn duplicates(&self) -> &[DuplicateComponent] {
        &self.duplicates
    }

    /// Component types refused because their name is not under their pack's.
    pub fn refused(&self) -> &[RefusedComponent] {
        &self.refused
    }

    /// Every registration, refused ones included, in the order a pack library exports them.
    pub(crate) fn exported(&self) -> impl Iterator<Item = &RegisteredComponent> {
        self.components.values().chain(&self.refused_registrations)
    }

    /// The descriptors of the diagram's instances whose ports depend on their properties, by id.
    ///
    /// A describe function that panics is reported as that instance's error, never propagated.
    pub(crate) fn instance_infos(&self, diagram: &Diagram) -> InstanceInfos {
        let mut infos = InstanceInfos::new();
        for instance in &diagram.components {
            let Some(registered) = self.components.get(&instance.type_name) else {
                continue;
            };
            let Some(describe) = &registered.describe else {
                continue;
            };
            let properties = kairos_diagram::resolved_properties(instance, &registered.info);
            let described = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| describe(&properties)))
                .unwrap_or_else(|_| {
                    Err(DescribeError {
                        property: None,
                        message: "the component panicked while describing its ports".to_owned(),
                        suggestion: None,
                    })
                })
                .map(|mut info| {
                    info.pack.clone_from(&registered.info.pack);
                    info.type_name.clone_from(&registered.info.type_name);
                    info
                });
            infos.insert(instance.id.clone(), described);
        }
        infos
    }

    /// Validates `diagram` against this registry, instances that describe themselves included; see
    /// [`kairos_diagram::validate_with`].
    pub(crate) fn validate(&self, diagram: &Diagram, source_map: Option<&SourceMap>) -> Vec<Diagnostic> {
        kairos_diagram::validate_with(
            diagram,
            source_map,
            &self.library_info(),
            &self.instance_infos(diagram),
        )
    }

    /// The library as plain data, for validation and listings.
    pub fn library_info(&self) -> LibraryInfo {
        LibraryInfo {
            packs: self.packs.clone(),
            components: self
                .components
                .iter()
                .map(|(name, c)| (name.clone(), c.info.clone()))
                .collect(),
            custom_types: self.custom_types.iter().cloned().collect(),
            instances: BTreeMap::new(),
            subgraphs: self.subgraphs.clone(),
        }
    }
}

/// Adds one pack's components to a [`Registry`].
#[derive(Debug)]
pub struct PackRegistrar<'a> {
    registry: &'a mut Registry,
    pack: String,
}

impl PackRegistrar<'_> {
    /// Registers a component type made by `Default`.
    pub fn component<C: Component + Default>(&mut self, info: ComponentInfo) -> &mut Self {
        self.component_with(info, || Box::new(C::default()))
    }

    /// Registers a component type made by `Default` whose ports depend on its properties: `describe`
    /// gives one instance's descriptor (validation and the engine use it instead of `info`).
    pub fn component_described<C: Component + Default>(
        &mut self,
        info: ComponentInfo,
        describe: impl Fn(&BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError>
        + Send
        + Sync
        + 'static,
    ) -> &mut Self {
        self.insert(
            info,
            Arc::new(|| Box::new(C::default())),
            Some(Arc::new(describe)),
        )
    }

    /// Ships a subgraph with the pack: a diagram (`text`, with an `exposes` section) that diagrams use
    /// as the component type `pack.name`, versioned with the pack.
    pub fn subgraph(&mut self, name: &str, text: &str) -> &mut Self {
        self.registry
            .subgraphs
            .insert(format!("{}.{name}", self.pack), text.to_owned());
        self
    }

    /// Registers a component type with its own factory.
    pub fn component_with(
        &mut self,
        info: ComponentInfo,
        factory: impl Fn() -> Box<dyn Component> + Send + Sync + 'static,
    ) -> &mut Self {
        self.insert(info, Arc::new(factory), None)
    }

    fn insert(&mut self, mut info: ComponentInfo, factory: Factory, describe: Option<Describe>) -> &mut Self {
        info.pack.clone_from(&self.pack);
        let under_pack = info
            .type_name
            .strip_prefix(self.pack.as_str())
            .and_then(|rest| rest.strip_prefix('.'))
            .is_some_and(|rest| !rest.is_empty());
        if !under_pack {
            let short_name = info.type_name.rsplit('.').next().unwrap_or_default();
            let origin = self
                .registry
                .packs
                .get(&self.pack)
                .map_or_else(String::new, |p| p.origin.clone());
            self.registry.refused_registrations.push(RegisteredComponent {
                info: info.clone(),
                factory,
                describe,
            });
            self.registry.refused.push(RefusedComponent {
                reason: format!(
                    "pack '{pack}' may register only types named '{pack}.…': '{}' is refused (name it '{pack}.{short_name}')",
                    info.type_name,
                    pack = self.pack
                ),
                type_name: info.type_name,
                pack: self.pack.clone(),
                origin,
            });
            return self;
        }
        if let Some(existing) = self.registry.components.get(&info.type_name) {
            self.registry.duplicates.push(DuplicateComponent {
                type_name: info.type_name.clone(),
                kept_from: existing.info.pack.clone(),
                refused_from: self.pack.clone(),
            });
            return self;
        }
        self.registry.components.insert(
            info.type_name.clone(),
            RegisteredComponent {
                info,
                factory,
                describe,
            },
        );
        self
    }

    /// Registers a pack-defined data type name.
    pub fn custom_type(&mut self, name: &str) -> &mut Self {
        self.registry.custom_types.insert(name.to_owned());
        self
    }
}

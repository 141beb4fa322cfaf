"""A detector plugin (an installed package's ``asg.detectors`` entry point, asg.perception.plugins):
it brings its own weights; its wrapper says whether it has attention."""
from __future__ import annotations

from sumo_scenarios.errors import InputError

from ..plugins import load_plugin, plugin_names
from .base import TARGET_KINDS, Target, shipped_list


@TARGET_KINDS.register("plugin")
class PluginTarget(Target):
    order = 20  # after the shipped models: a shipped name wins over a plugin's
    header = "plugins"

    @classmethod
    def claims(cls, name: str) -> bool:
        return name in plugin_names()

    @classmethod
    def help_names(cls) -> list[str]:
        return plugin_names()

    def detector(self, weights_file: str | None = None, **options):
        self._no_options(options)
        self.check(weights_file)
        return load_plugin(self.name)

    def check(self, weights_file: str | None = None) -> "PluginTarget":
        """Its name only (a plugin is built where it runs); a ``weights_file`` is refused."""
        if weights_file:
            raise InputError(f"--weights applies to the shipped models; the plugin '{self.name}' loads its own")
        return self

    @property
    def borrows_attention(self) -> bool:
        return False  # its own wrapper answers attention_weights (None: ACS-A borrows then)

    def not_trained_here(self) -> str:
        return (f"'{self.name}' is a detector plugin: it brings its own weights, and asg trains, fine-tunes and "
                f"hardens the shipped models only ({shipped_list()})")

"""Reading a configuration file as a careful user would hope and a hostile one would not: bounded in size and
memory, UTF-8 text, no YAML aliases, identifiers read as written.

- Size: a rig configuration is a few kilobytes; a file above MAX_CONFIG_BYTES is refused before it is parsed.
- Aliases: an alias (`*name`) repeats an anchored node, and aliases of aliases expand exponentially (the
  "billion laughs" bomb: a kilobyte of YAML, gigabytes of objects). Anchors and aliases are refused while the
  document is composed, before anything is built.
- Identifiers: YAML 1.1 reads `0123456` as octal (42798) and `12:34:56` as base 60 (45296); a serial number
  so read opens the wrong camera. For keys the schema types as text, and for every mapping key (all names),
  the scalar's own source text is kept.
- Messages: every refusal is a ConfigError naming the file, with any quoted text cut to a short excerpt.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from ntcr_recon.core.base.schema import ConfigError, excerpt

MAX_CONFIG_BYTES = 1 << 20  # 1 MiB: two hundred times the largest rig configuration
MAX_MESSAGE_CHARS = 400     # a parser message quoting a long line is cut to this

TextPath = Callable[[tuple[str, ...]], bool]  # whether the value at a key path is text (str) in the schema


class _NoAliasLoader(yaml.SafeLoader):
    """SafeLoader composing a node graph that refuses anchors and aliases as soon as it meets one."""

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
            kind = "alias *" if isinstance(event, yaml.AliasEvent) else "anchor &"
            raise ConfigError(f"line {event.start_mark.line + 1}: YAML {kind}{excerpt(event.anchor)[1:-1]} is "
                              "refused: anchors and aliases are not used in a rig configuration (and aliases "
                              "that expand can exhaust memory); write the values out")
        return super().compose_node(parent, index)


def read_config_document(path: Path, what: str, is_text: TextPath) -> Any:
    """The document of a YAML file; ConfigError naming the file when it cannot be read as one."""
    try:
        with open(path, "rb") as stream:
            data = stream.read(MAX_CONFIG_BYTES + 1)
    except OSError as error:
        raise ConfigError(f"cannot read {what} {path}: {error.strerror or error}") from error
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{what} {path} is larger than {MAX_CONFIG_BYTES // 1024} KiB: not a configuration file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ConfigError(f"{what} {path} is not UTF-8 text (byte 0x{data[error.start]:02x} at offset "
                          f"{error.start}): is it a YAML file?") from None
    loader = None
    try:
        loader = _NoAliasLoader(text)  # its reader refuses control characters already
        node = loader.get_single_node()
        return None if node is None else _construct(loader, node, (), is_text)
    except ConfigError as error:
        raise ConfigError(f"{what} {path}: {error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(f"{what} {path} is not valid YAML: {_cut(str(error))}") from None
    except RecursionError:
        raise ConfigError(f"{what} {path} is nested too deeply to be a configuration") from None
    finally:
        if loader is not None:
            loader.dispose()


def _construct(loader: yaml.SafeLoader, node: yaml.Node, path: tuple[str, ...], is_text: TextPath) -> Any:
    """The Python value of a composed node; the scalars of text keys as written in the file."""
    line = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        loader.flatten_mapping(node)  # resolves `<<` merge keys (refused above when they use aliases)
        result: dict = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                raise ConfigError(f"line {key_node.start_mark.line + 1}: a key must be a name, not a "
                                  f"{'mapping' if isinstance(key_node, yaml.MappingNode) else 'list'}")
            key = key_node.value  # every key is a name: `0123:` (a camera) is not the octal number 83
            if key in result:
                raise ConfigError(f"line {key_node.start_mark.line + 1}: key {excerpt(key)} appears twice")
            result[key] = _construct(loader, value_node, path + tuple(str(key).split(".")), is_text)
        return result
    if isinstance(node, yaml.SequenceNode):
        return [_construct(loader, item, path + ("[]",), is_text) for item in node.value]
    if is_text(path) and node.tag != "tag:yaml.org,2002:null":
        return node.value  # the source text: no octal, base-60, float or boolean reading of an identifier
    try:
        return loader.construct_object(node, deep=True)
    except (ValueError, OverflowError) as error:  # e.g. an integer beyond Python's digit limit
        raise ConfigError(f"line {line}: cannot read the value of {'.'.join(path) or 'the document'}: "
                          f"{_cut(str(error))}") from None


def _cut(message: str) -> str:
    return message if len(message) <= MAX_MESSAGE_CHARS else message[:MAX_MESSAGE_CHARS] + " [...]"

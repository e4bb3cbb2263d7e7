"""Who may open the port: the user's groups (``perm.group``), a group added without
a new login (``perm.relogin``), a container's group ids (``container.gid``) and the
user of a systemd unit that names the port (``unit.user_group``)."""
from __future__ import annotations

import os
import re
from typing import Iterator, List, Optional, Set

from .._context import Context
from .._finding import Finding
from .._registry import check
from ._common import device_owner, group_line, group_name, mentions, names_of

#: what /proc/1/cgroup says inside a container
_CONTAINER_RE = re.compile(r"docker|kubepods|containerd|libpod|lxc|podman")


def _may_open(uid: int, gids: List[int], owner: tuple) -> bool:
    o_uid, o_gid, mode, _ = owner
    if uid == 0:
        return True
    if uid == o_uid and mode & 0o600 == 0o600:
        return True
    if o_gid in gids and mode & 0o060 == 0o060:
        return True
    return mode & 0o006 == 0o006


@check("perm.group", "the user's groups let it open the port")
def perm_group(ctx: Context) -> Iterator[Finding]:
    if not ctx.user:
        yield Finding("perm.group", "info", "no user to check: give --user NAME",
                      [f"user: {ctx.user_source}"])
        return
    u = ctx.user_by_name(ctx.user)
    if u is None:
        yield Finding("perm.group", "info", f"user {ctx.user} is not in /etc/passwd: not checked",
                      [f"user: {ctx.user} ({ctx.user_source})"])
        return
    for port in ctx.ports():
        owner = device_owner(ctx, port)
        if owner is None:
            continue
        gids = ctx.gids_of(u.name)
        ev = [owner[3], f"/etc/passwd:{u.line}: {u.name} uid {u.uid} gid {u.gid}"] + \
            group_line(ctx, owner[1])
        if _may_open(u.uid, gids, owner):
            yield Finding("perm.group", "ok", f"{u.name} may open {port.device}", ev,
                          port=port.device)
        elif ctx.group_by_gid(owner[1]) is None:
            yield Finding("perm.group", "warning",
                          f"{port.device}'s group (gid {owner[1]}) has no name in /etc/group, "
                          f"so {u.name} cannot be in it", ev,
                          "see container.gid; on a host: `sudo udevadm trigger` restores the "
                          "udev default group (dialout)", port=port.device)
        else:
            g = group_name(ctx, owner[1])
            yield Finding("perm.group", "error",
                          f"{u.name} is not in group {g}, which owns {port.device}", ev,
                          f"sudo usermod -aG {g} {u.name}   # then log out and in again "
                          "(or reboot): groups apply at login", port=port.device)


def _process_groups(ctx: Context, uid: int) -> Optional[tuple]:
    """(gids of the checked user's login, evidence) or None when not known."""
    if ctx.live:
        if os.getuid() != uid:
            return None
        gids = set(os.getgroups()) | {os.getgid()}
        return gids, f"this process (uid {uid}): groups {' '.join(map(str, sorted(gids)))}"
    status = ctx.lines("/proc/self/status")
    uid_line = next((ln for ln in status if ln.startswith("Uid:")), None)
    groups_line = next((ln for ln in status if ln.startswith("Groups:")), None)
    if not uid_line or groups_line is None or uid_line.split()[1:2] != [str(uid)]:
        return None
    gids = {int(x) for x in groups_line.split()[1:] if x.isdigit()}
    gid_line = next((ln for ln in status if ln.startswith("Gid:")), "")
    gids |= {int(x) for x in gid_line.split()[1:2] if x.isdigit()}
    return gids, f"/proc/self/status: {groups_line.strip()}"


@check("perm.relogin", "a group added to the user is active in its login")
def perm_relogin(ctx: Context) -> Iterator[Finding]:
    u = ctx.user_by_name(ctx.user) if ctx.user else None
    if u is None or u.uid == 0:
        return
    proc = _process_groups(ctx, u.uid)
    if proc is None:
        return
    have, ev_proc = proc
    for port in ctx.ports():
        owner = device_owner(ctx, port)
        if owner is None:
            continue
        g = ctx.group_by_gid(owner[1])
        if g is None or u.name not in g.members:
            continue
        if owner[1] in have:
            yield Finding("perm.relogin", "ok", f"group {g.name} is active in {u.name}'s login",
                          [ev_proc], port=port.device)
        else:
            yield Finding("perm.relogin", "error",
                          f"{u.name} was added to {g.name} but has not logged in again: "
                          "the running session lacks the group",
                          [ev_proc + f" (no {g.gid})"] + group_line(ctx, g.gid) + [owner[3]],
                          f"log out and in again (or reboot; in one shell: `newgrp {g.name}`); "
                          f"a user service: `sudo systemctl restart user@{u.uid}.service`",
                          port=port.device)


def in_container(ctx: Context) -> Optional[str]:
    """Evidence that the analysed system is a container, or None."""
    for marker in ("/.dockerenv", "/run/.containerenv"):
        if ctx.exists(marker):
            return f"{marker} exists"
    for n, line in enumerate(ctx.lines("/proc/1/cgroup"), 1):
        if _CONTAINER_RE.search(line):
            return f"/proc/1/cgroup:{n}: {line.strip()[:160]}"
    return None


@check("container.gid", "inside a container, the device's group exists there")
def container_gid(ctx: Context) -> Iterator[Finding]:
    where = in_container(ctx)
    if where is None:
        return
    for port in ctx.ports():
        owner = device_owner(ctx, port)
        if owner is None:
            continue
        gid = owner[1]
        if ctx.group_by_gid(gid) is None:
            yield Finding("container.gid", "error",
                          f"in a container, {port.device}'s group id {gid} (the host's) has no "
                          "entry in the container's /etc/group: its users are not in it",
                          [where, owner[3], f"/etc/group: no group with gid {gid}"],
                          f"docker run --group-add {gid} ... (compose: `group_add: [\"{gid}\"]`), "
                          f"or in the image: `groupadd -g {gid} hostserial && usermod -aG "
                          f"hostserial USER`", port=port.device)
        else:
            yield Finding("container.gid", "ok",
                          f"in a container; {port.device}'s group {group_name(ctx, gid)} exists "
                          "here", [where, owner[3]], port=port.device)


def _unit_user_ok(ctx: Context, user: str, gid: int, unit_groups: Set[str]) -> bool:
    g = ctx.group_by_gid(gid)
    if g is not None and g.name in unit_groups or str(gid) in unit_groups:
        return True
    return gid in ctx.gids_of(user)


@check("unit.user_group", "the user of a systemd unit naming the port may open it")
def unit_user_group(ctx: Context) -> Iterator[Finding]:
    for port in ctx.ports():
        owner = device_owner(ctx, port)
        if owner is None:
            continue
        names = names_of(ctx, port)
        for unit in ctx.units().values():
            line = mentions(unit.text, port, names)
            if line is None:
                continue
            users = unit.values("User")
            dynamic = any(v.lower() in ("yes", "true", "1") for _, v in unit.values("DynamicUser"))
            groups = {g for _, v in unit.values("SupplementaryGroups") + unit.values("Group")
                      for g in v.split()}
            user = users[-1][1] if users else ("(dynamic)" if dynamic else "root")
            ev = [f"{unit.path}:{line}: names {port.device}"] + \
                ([f"{unit.path}:{users[-1][0]}: User={user}"] if users else
                 [f"{unit.path}: no User= (runs as {user})"])
            if user in ("root", "0") and not dynamic:
                yield Finding("unit.user_group", "ok", f"{unit.name} runs as root", ev,
                              port=port.device)
                continue
            gname = group_name(ctx, owner[1])
            if _unit_user_ok(ctx, user, owner[1], groups):
                yield Finding("unit.user_group", "ok",
                              f"{unit.name}'s user {user} is in {gname}", ev, port=port.device)
                continue
            yield Finding("unit.user_group", "error",
                          f"{unit.name} runs as {user}, which is not in {gname} "
                          f"(the group of {port.device})", ev + [owner[3]],
                          f"sudo usermod -aG {gname} {user}, or `sudo systemctl edit "
                          f"{unit.name}` with:\n[Service]\nSupplementaryGroups={gname}\n"
                          f"then `sudo systemctl restart {unit.name}`", port=port.device)

-- Wireshark dissectors for pcap files written by `fap monitor --pcap`
-- (FAP, exec async, mikroC RS-485, Gicren G485). Shipped in fap_py;
-- `fap monitor --dissectors DIR` writes this file. See docs/monitor.md.
--
-- Link type LINKTYPE_USER0 (147). Each packet: a header
--   version u8 (1) | protocol u8 (1 fap, 2 exec, 3 mikroc, 4 g485) |
--   flags u8 (bit0 ok, bit1 port known, bit2 time known) | port u8 |
--   text length u8 | text (error reason, or FAP msg_name / G485 packet)
-- then the frame as it was on the wire. The monitor decoded the frame
-- with the protocol's own codec and wrote its verdict into the header;
-- these dissectors only show the fields of a good frame, they never judge
-- a frame themselves (no CRC is computed here).
--
-- Display filters: fapmon.ok, fapmon.error, fapmon.port, fap.src, fap.dst,
-- fap.msg, execasync.node, execasync.seq, mikroc.address, g485.address,
-- g485.pid, g485.device ... ("exec" is taken by Wireshark's rexec dissector).
-- The Source and Destination columns show who sent a frame and to whom
-- (node numbers, "master"); a G485 reply carries the master's address, its
-- device is the one the last request asked (as the monitor's JSON "device").

local PROTOCOL_NAMES = { [1] = "fap", [2] = "exec", [3] = "mikroc", [4] = "g485" }

-- the record header ------------------------------------------------------
local mon = Proto("fapmon", "fap monitor record")
local h_version = ProtoField.uint8("fapmon.version", "Header version")
local h_protocol = ProtoField.string("fapmon.protocol", "Protocol")
local h_ok = ProtoField.bool("fapmon.ok", "Frame ok")
local h_error = ProtoField.string("fapmon.error", "Error")
local h_port = ProtoField.uint8("fapmon.port", "Sender port")
local h_frame = ProtoField.bytes("fapmon.frame", "Frame", base.NONE)
mon.fields = { h_version, h_protocol, h_ok, h_error, h_port, h_frame }

-- FAP: marker | size u16 LE | msg | dst | src | data | CRC u16 LE ---------
local fap = Proto("fap", "FAP")
local fap_size = ProtoField.uint16("fap.size", "Size", base.DEC)
local fap_msg = ProtoField.uint8("fap.msg", "Message", base.DEC)
local fap_msg_name = ProtoField.string("fap.msg_name", "Message name")
local fap_dst = ProtoField.uint8("fap.dst", "Destination", base.DEC)
local fap_src = ProtoField.uint8("fap.src", "Source", base.DEC)
local fap_data = ProtoField.bytes("fap.data", "Data", base.NONE)
local fap_crc = ProtoField.uint16("fap.crc", "CRC", base.HEX)
fap.fields = { fap_size, fap_msg, fap_msg_name, fap_dst, fap_src, fap_data, fap_crc }

local function dissect_fap(tvb, tree, text, pinfo)
    pinfo.cols.src = tostring(tvb(12, 1):uint())
    pinfo.cols.dst = tostring(tvb(11, 1):uint())
    local t = tree:add(fap, tvb())
    local size = tvb(8, 2):le_uint()
    t:add_le(fap_size, tvb(8, 2))
    t:add(fap_msg, tvb(10, 1))
    t:add(fap_msg_name, text)
    t:add(fap_dst, tvb(11, 1))
    t:add(fap_src, tvb(12, 1))
    if size > 13 then t:add(fap_data, tvb(13, size - 13)) end
    t:add_le(fap_crc, tvb(size, 2))
    return string.format("%s %d -> %d, %d bytes", text, tvb(12, 1):uint(), tvb(11, 1):uint(),
                         size - 13)
end

-- exec async: DLE STX | node | seq | data (DLE doubled) | DLE ETX | CRC BE --
local ex = Proto("execasync", "Exec async")
local ex_node = ProtoField.uint8("execasync.node", "Node", base.DEC)
local ex_seq = ProtoField.uint8("execasync.seq", "Sequence", base.DEC)
local ex_data = ProtoField.bytes("execasync.data", "Data", base.NONE)
local ex_crc = ProtoField.uint16("execasync.crc", "CRC", base.HEX)
ex.fields = { ex_node, ex_seq, ex_data, ex_crc }

local DLE = 0x10

local EXEC_BROADCAST = 255
local exec_pending = nil        -- first pass: node/seq of the last request
local exec_answer = {}          -- frame number -> true for an answer

local function dissect_exec(tvb, tree, text, pinfo)
    local t = tree:add(ex, tvb())
    -- a request and its answer carry the same node and sequence number: the
    -- frame after a request with the same pair is the answer (as the statistics pair them)
    local node = tvb(2, 1):uint()
    if not pinfo.visited then
        local key = node * 256 + tvb(3, 1):uint()
        if node == EXEC_BROADCAST then
            exec_answer[pinfo.number] = false
        elseif exec_pending == key then
            exec_answer[pinfo.number] = true
            exec_pending = nil
        else
            exec_answer[pinfo.number] = false
            exec_pending = key
        end
    end
    if node == EXEC_BROADCAST then
        pinfo.cols.src, pinfo.cols.dst = "master", "all"
    elseif exec_answer[pinfo.number] then
        pinfo.cols.src, pinfo.cols.dst = "node " .. node, "master"
    else
        pinfo.cols.src, pinfo.cols.dst = "master", "node " .. node
    end
    local n = tvb:len()
    t:add(ex_node, tvb(2, 1))
    t:add(ex_seq, tvb(3, 1))
    -- the data as sent sits between the seq byte and DLE ETX; a doubled DLE is one data byte
    local stuffed = tvb(4, n - 8):bytes()
    local data = ByteArray.new()
    local i = 0
    while i < stuffed:len() do
        local b = stuffed:get_index(i)
        data:append(ByteArray.new(string.format("%02x", b)))
        i = i + ((b == DLE) and 2 or 1)
    end
    if data:len() > 0 then
        t:add(ex_data, data:tvb("exec async data")())
    end
    t:add(ex_crc, tvb(n - 2, 2))
    return string.format("node %d seq %d, %d bytes", tvb(2, 1):uint(), tvb(3, 1):uint(), data:len())
end

-- mikroC: 0x96 | address | DATALEN | data 0..3 | crc | 0xA9 ----------------
-- DATALEN: bit7 master, bit6 address XORed with 1, bits 2..4 data i XORed, bits 0..1 count
local mk = Proto("mikroc", "mikroC RS-485")
local mk_address = ProtoField.uint8("mikroc.address", "Address", base.DEC)
local mk_master = ProtoField.bool("mikroc.from_master", "From master")
local mk_datalen = ProtoField.uint8("mikroc.datalen", "DATALEN", base.HEX)
local mk_data = ProtoField.bytes("mikroc.data", "Data", base.NONE)
mk.fields = { mk_address, mk_master, mk_datalen, mk_data }

local function dissect_mikroc(tvb, tree, text, pinfo)
    local t = tree:add(mk, tvb())
    local dl = tvb(2, 1):uint()
    local addr = tvb(1, 1):uint()
    if bit.band(dl, 0x40) ~= 0 then addr = bit.bxor(addr, 1) end
    if bit.band(dl, 0x80) ~= 0 then
        pinfo.cols.src, pinfo.cols.dst = "master", tostring(addr)
    else
        pinfo.cols.src, pinfo.cols.dst = tostring(addr), "master"
    end
    t:add(mk_address, tvb(1, 1), addr)
    t:add(mk_master, tvb(2, 1), bit.band(dl, 0x80) ~= 0)
    t:add(mk_datalen, tvb(2, 1))
    local count = bit.band(dl, 0x03)
    if count > 0 then
        local data = ByteArray.new()
        for i = 0, count - 1 do
            local b = tvb(3 + i, 1):uint()
            if bit.band(dl, bit.lshift(0x04, i)) ~= 0 then b = bit.bxor(b, 1) end
            data:append(ByteArray.new(string.format("%02x", b)))
        end
        t:add(mk_data, data:tvb("mikroC data")())
    end
    return string.format("%s %d, %d bytes", bit.band(dl, 0x80) ~= 0 and "master ->" or "slave",
                         addr, count)
end

-- G485: FF FF | (address << 1) | R/W | LENGTH | PID | data | CHECK ----------
local g4 = Proto("g485", "Gicren G485")
local g4_address = ProtoField.uint8("g485.address", "Address", base.DEC)
local g4_rw = ProtoField.uint8("g485.rw", "R/W (1 read)", base.DEC)
local g4_length = ProtoField.uint8("g485.length", "Length", base.DEC)
local g4_pid = ProtoField.uint8("g485.pid", "PID", base.HEX)
local g4_data = ProtoField.bytes("g485.data", "Data", base.NONE)
local g4_packet = ProtoField.string("g485.packet", "Packet")
local g4_check = ProtoField.uint8("g485.check", "Check", base.HEX)
local g4_device = ProtoField.uint8("g485.device", "Device (asked, or answering)", base.DEC)
g4.fields = { g4_address, g4_rw, g4_length, g4_pid, g4_data, g4_packet, g4_check, g4_device }

local G485_PREAMBLE = "Wake-up-Preamble"
local G485_REPLY = 0xFF          -- the address byte of every reply: master 127, read
local g485_asked = nil           -- first pass: the address the last request asked
local g485_device = {}           -- frame number -> device

local function dissect_g485(tvb, tree, text, pinfo)
    local t = tree:add(g4, tvb())
    local n = tvb:len()
    if text == G485_PREAMBLE then
        t:add(g4_data, tvb())
        t:add(g4_packet, text)
        pinfo.cols.src, pinfo.cols.dst = "master", "all"
        return string.format("%s, %d bytes", text, n)
    end
    local a = tvb(2, 1):uint()
    if not pinfo.visited then
        if a ~= G485_REPLY then g485_asked = bit.rshift(a, 1) end
        g485_device[pinfo.number] = g485_asked
    end
    local device = g485_device[pinfo.number]
    if a == G485_REPLY then
        pinfo.cols.src = device ~= nil and tostring(device) or "?"
        pinfo.cols.dst = "master"
    else
        pinfo.cols.src, pinfo.cols.dst = "master", tostring(bit.rshift(a, 1))
    end
    t:add(g4_address, tvb(2, 1), bit.rshift(a, 1))
    t:add(g4_rw, tvb(2, 1), bit.band(a, 1))
    t:add(g4_length, tvb(3, 1))
    t:add(g4_pid, tvb(4, 1))
    if n > 6 then t:add(g4_data, tvb(5, n - 6)) end
    t:add(g4_packet, text)
    t:add(g4_check, tvb(n - 1, 1))
    if device ~= nil then t:add(g4_device, device) end
    if a == G485_REPLY then
        return string.format("%s from %s", text, device ~= nil and tostring(device) or "?")
    end
    return string.format("%s address %d", text, bit.rshift(a, 1))
end

local DISSECT = { fap = dissect_fap, exec = dissect_exec, mikroc = dissect_mikroc,
                  g485 = dissect_g485 }
local COLUMN = { fap = "FAP", exec = "EXEC", mikroc = "MIKROC", g485 = "G485" }

function mon.init()
    g485_asked = nil
    g485_device = {}
    exec_pending = nil
    exec_answer = {}
end

function mon.dissector(tvb, pinfo, tree)
    if tvb:len() < 5 then return 0 end
    local tlen = tvb(4, 1):uint()
    local hlen = 5 + tlen
    local name = PROTOCOL_NAMES[tvb(1, 1):uint()] or "?"
    local flags = tvb(2, 1):uint()
    local ok = bit.band(flags, 1) ~= 0
    local text = tlen > 0 and tvb(5, tlen):string() or ""
    local h = tree:add(mon, tvb(0, hlen))
    h:add(h_version, tvb(0, 1))
    h:add(h_protocol, tvb(1, 1), name)
    h:add(h_ok, tvb(2, 1), ok)
    if not ok then h:add(h_error, tvb(5, tlen), text) end
    if bit.band(flags, 2) ~= 0 then h:add(h_port, tvb(3, 1)) end
    pinfo.cols.protocol = COLUMN[name] or "FAPMON"
    if tvb:len() <= hlen then
        pinfo.cols.info = "empty record"
        return tvb:len()
    end
    local frame = tvb(hlen):tvb()
    tree:add(h_frame, frame())
    if ok and DISSECT[name] then
        pinfo.cols.info = DISSECT[name](frame, tree, text, pinfo)
    else
        -- a bad frame's fields are not trusted: the sender port is all that is known
        if bit.band(flags, 2) ~= 0 then pinfo.cols.src = "port " .. tvb(3, 1):uint() end
        pinfo.cols.info = string.format("[%s] %d bytes", text, frame:len())
        tree:add_expert_info(PI_MALFORMED, PI_ERROR, "bad frame: " .. text)
    end
    return tvb:len()
end

DissectorTable.get("wtap_encap"):add(wtap_encaps.USER0, mon)
